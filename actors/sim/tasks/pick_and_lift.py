"""L2 pick_and_lift: grasp the target block (random yaw, two distractors) and lift it into the target zone."""

from __future__ import annotations

import numpy as np
from actors.sim.bullet import p

from actors.sim import shapes
from actors.sim.tasks.base import Task, sample_positions, top_down, waypoint

HALF = 0.0225  #: block half size


class PickAndLift(Task):
    name = "pick_and_lift"
    episode_length = 6

    def sample(self, rng):
        pts = sample_positions(rng, 3, (0.35, -0.25, HALF), (0.6, 0.25, HALF), 0.12)
        self.blocks = pts
        self.yaws = rng.uniform(-np.pi / 4, np.pi / 4, 3)
        names = list(rng.choice(list(shapes.COLOURS), 3, replace=False))
        self.colours = [shapes.COLOURS[n] for n in names]
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
