"""L0 reach_target: touch the red sphere among three; success when the grasp frame is within 2 cm."""

from __future__ import annotations

import numpy as np

from actors.sim import shapes
from actors.sim.tasks.base import Task, sample_positions, top_down, waypoint


class ReachTarget(Task):
    name = "reach_target"

    def sample(self, rng):
        self.spheres = sample_positions(rng, 3, (0.3, -0.3, 0.05), (0.65, 0.3, 0.4), 0.2)
        self.colours = shapes.target_and_distractors(rng, 2)

    def spawn(self, client):
        return {f"sphere{i}": shapes.sphere(client, 0.025, pos, shapes.COLOURS[c], collide=False)
                for i, (pos, c) in enumerate(zip(self.spheres, self.colours))}

    def waypoints(self):
        return [waypoint(self.spheres[0], top_down(0.0), 1.0)]

    def success(self):
        return bool(np.linalg.norm(self.scene.grasp_pose()[:3] - self.spheres[0]) < 0.02)
