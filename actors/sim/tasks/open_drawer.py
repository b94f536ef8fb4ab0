"""L4 open_drawer: pull the bottom drawer (RLBench's variation 0) out by 15 cm, approaching horizontally."""

from __future__ import annotations

import numpy as np

from actors.sim.tasks import drawer_chest as chest
from actors.sim.tasks.base import Task, waypoint, yaw_rotate
from actors.sim.tasks.drawer_chest import LEGS, VARIATION

OPENED = 0.15


class OpenDrawer(Task):
    name = "open_drawer"
    obstacles = ("chest",)

    def sample(self, rng):
        self.variation = VARIATION
        self.yaw = rng.uniform(-np.pi / 8, np.pi / 8)
        self.position = np.array([rng.uniform(0.8, 0.85), rng.uniform(-0.15, 0.15), LEGS])

    def spawn(self, client):
        return {"chest": chest.spawn(client, self.position, self.yaw)}

    def planner_ignores(self):
        return [("chest", chest.handle_link(k)) for k in range(3)]

    def graspables(self):
        return [(self.bodies["chest"], chest.handle_link(k)) for k in range(3)]

    def waypoints(self):
        k, q = self.variation, chest.handle_grasp_quaternion(self.yaw)
        h = chest.handle_position(self.position, self.yaw, k)
        back = yaw_rotate(self.yaw, (-1.0, 0.0, 0.0))
        return [waypoint(h + chest.APPROACH_DISTANCE * back, q, 1.0), waypoint(h, q, 0.0),
                waypoint(h + 0.2 * back, q, 0.0, linear=True)]

    def success(self):
        return self.joint_position("chest", chest.drawer_link(self.variation)) > OPENED
