"""L5 put_in_bin (put_rubbish_in_bin): pick the rubbish block, drop it in the bin, let go.

Success needs the rubbish inside the bin AND nothing grasped, so the release is part of the task.
"""

from __future__ import annotations

import numpy as np

from actors.sim import shapes
from actors.sim.bullet import p
from actors.sim.tasks.base import Task, sample_positions, top_down, waypoint

HALF = 0.02
BIN_HALF, BIN_WALL, BIN_H = 0.09, 0.005, 0.07
#: The grasp frame's height over the bin's floor where the demo lets go: the held block's bottom clears the
#: rim by 4 cm. Revision 1 let go at 0.20, 13 cm above the rim, where the cascade's finer cubes held no
#: point of the bin (bench/cube_occupancy.py: 0 occupied voxels at (8,8,8)'s last depth in 5 of 5 demos,
#: 5-21 at 0.13) and so could not learn where over the bin to go.
RELEASE_HEIGHT = 0.13
#: The approach keyframe's height over the block's centre. Revision 2 approached 10 cm above it, where the
#: last depth's 15 cm cube began 2.5 cm above the block's top (5-7 occupied voxels, all at its edge): greedy
#: approach poses landed 10.5 cm off and hovered there for the rest of the episode.
PRE_GRASP_HEIGHT = 0.05


class PutInBin(Task):
    name = "put_in_bin"
    obstacles = ("bin",)

    def sample(self, rng):
        side = rng.choice([-1.0, 1.0])
        self.bin = np.array([rng.uniform(0.45, 0.6), side * rng.uniform(0.2, 0.28), 0.0])
        ys = sorted((-side * 0.28, side * 0.05))
        pts = sample_positions(rng, 3, (0.35, ys[0], HALF), (0.6, ys[1], HALF), 0.1)
        self.items = pts  # rubbish first, then two "tomatoes"
        self.yaw = rng.uniform(-np.pi / 4, np.pi / 4)

    def spawn(self, client):
        b, w, h = BIN_HALF, BIN_WALL, BIN_H
        parts = [("box", (b, b, w), (0, 0, w)), ("box", (w, b, h / 2), (b - w, 0, h / 2)),
                 ("box", (w, b, h / 2), (-b + w, 0, h / 2)), ("box", (b, w, h / 2), (0, b - w, h / 2)),
                 ("box", (b, w, h / 2), (0, -b + w, h / 2))]
        bodies = {"bin": shapes.compound(client, parts, self.bin, rgba=(0.3, 0.3, 0.35, 1))}
        bodies["rubbish"] = shapes.box(client, (HALF,) * 3, self.items[0], p.getQuaternionFromEuler((0, 0, self.yaw)),
                                       rgba=(0.9, 0.9, 0.85, 1), mass=0.05)
        for i in (1, 2):
            bodies[f"tomato{i}"] = shapes.sphere(client, 0.025, self.items[i] + (0, 0, 0.005), (0.8, 0.1, 0.1, 1),
                                                 mass=0.05)
        return bodies

    def graspables(self):
        return [(self.bodies["rubbish"], -1)]

    def waypoints(self):
        pos, _ = self.pose_of("rubbish")
        q = top_down(self.yaw)
        above_bin = self.bin + (0, 0, RELEASE_HEIGHT)
        return [waypoint(pos + (0, 0, PRE_GRASP_HEIGHT), q, 1.0), waypoint(pos, q, 0.0),
                waypoint(pos + (0, 0, 0.2), q, 0.0), waypoint(above_bin, q, 0.0), waypoint(above_bin, q, 1.0)]

    def success(self):
        pos, _ = self.pose_of("rubbish")
        inside = np.all(np.abs(pos[:2] - self.bin[:2]) < BIN_HALF - BIN_WALL) and pos[2] < BIN_H
        return bool(inside) and self.nothing_grasped()
