"""L2 pick_and_lift: grasp the red target block (random yaw, two distractors) and lift it into the target zone.

RLBench's variation 0, as C2F-ARM: the target is red, the distractors other colours.
"""

from __future__ import annotations

import numpy as np

from actors.sim import shapes
from actors.sim.bullet import p
from actors.sim.tasks.base import Task, sample_positions, top_down, waypoint

HALF = 0.0225  #: block half size


class PickAndLift(Task):
    name = "pick_and_lift"
    #: the planner keeps the open hand off every block (contacts already there when a move starts, as
    #: with the block held, are exempt for that move)
    obstacles = ("block0", "block1", "block2")

    def sample(self, rng):
        pts = sample_positions(rng, 3, (0.35, -0.25, HALF), (0.6, 0.25, HALF), 0.12)
        self.blocks = pts
        self.yaws = rng.uniform(-np.pi / 4, np.pi / 4, 3)
        self.colours = [shapes.COLOURS[n] for n in shapes.target_and_distractors(rng, 2)]
        self.zone = np.array([rng.uniform(0.35, 0.55), rng.uniform(-0.2, 0.2), rng.uniform(0.2, 0.3)])

    def spawn(self, client):
        bodies = {f"block{i}": shapes.box(client, (HALF,) * 3, pos, p.getQuaternionFromEuler((0, 0, yaw)), rgba=c,
                                          mass=0.1)
                  for i, (pos, yaw, c) in enumerate(zip(self.blocks, self.yaws, self.colours))}
        bodies["zone"] = shapes.sphere(client, 0.03, self.zone, (*self.colours[0][:3], 0.4), collide=False)
        return bodies

    def graspables(self):
        return [(self.bodies[f"block{i}"], -1) for i in range(3)]

    def waypoints(self):
        pos, _ = self.pose_of("block0")
        q = top_down(self.yaws[0])
        return [waypoint(pos + (0, 0, 0.1), q, 1.0), waypoint(pos, q, 0.0), waypoint(self.zone, q, 0.0)]

    def success(self):
        pos, _ = self.pose_of("block0")
        return self.scene.is_grasped(self.bodies["block0"]) and bool(np.linalg.norm(pos - self.zone) < 0.05)
