"""L7 put_item_in_drawer: open a drawer, then pick the block beside the chest and drop it inside.

Long horizon (8 keyframes), and once the block is in the drawer the front camera barely sees it.
"""

from __future__ import annotations

import numpy as np

from actors.sim import shapes
from actors.sim.bullet import p
from actors.sim.tasks import drawer_chest as chest
from actors.sim.tasks.base import Task, top_down, waypoint, yaw_rotate
from actors.sim.tasks.drawer_chest import LEGS

HALF = 0.02
OPENED = 0.2
#: The free-air keyframes stay 10-15 cm from what they lead to, where the last depth's cube holds no point of it
#: (bench/cube_occupancy.py). Lowering them to 5 cm (as open_drawer, put_in_bin and stack_wine do) dropped the
#: scripted demos to 8 of 10 (bench/keyframes_executed.py), so it waits for a check of why.
APPROACH = 0.1


class PutItemInDrawer(Task):
    name = "put_item_in_drawer"
    obstacles = ("chest",)

    def sample(self, rng):
        self.variation = int(rng.integers(3))
        self.yaw = rng.uniform(-np.pi / 8, np.pi / 8)
        side = rng.choice([-1.0, 1.0])
        self.position = np.array([rng.uniform(0.8, 0.85), side * rng.uniform(0.08, 0.14), LEGS])
        self.block = np.array([rng.uniform(0.35, 0.5), -side * rng.uniform(0.22, 0.3), HALF])
        self.block_yaw = rng.uniform(-np.pi / 4, np.pi / 4)

    def spawn(self, client):
        return {"chest": chest.spawn(client, self.position, self.yaw),
                "block": shapes.box(client, (HALF,) * 3, self.block, p.getQuaternionFromEuler((0, 0, self.block_yaw)),
                                    rgba=(0.1, 0.5, 0.9, 1), mass=0.05)}

    def planner_ignores(self):
        return [("chest", chest.handle_link(k)) for k in range(3)]

    def graspables(self):
        return [(self.bodies["chest"], chest.handle_link(k)) for k in range(3)] + [(self.bodies["block"], -1)]

    def waypoints(self):
        k, qh = self.variation, chest.handle_grasp_quaternion(self.yaw)
        h = chest.handle_position(self.position, self.yaw, k)
        back = yaw_rotate(self.yaw, (-1.0, 0.0, 0.0))
        pulled = h + OPENED * back
        pos, _ = self.pose_of("block")
        qb = top_down(self.block_yaw)
        inside = chest.interior_centre(self.position, self.yaw, k, OPENED) + (0, 0, HALF + 0.03)
        qd = top_down(self.yaw)  # the hand's long side parallel to the chest front: it stays clear of the carcass
        return [waypoint(h + APPROACH * back, qh, 1.0), waypoint(h, qh, 0.0),
                waypoint(pulled, qh, 1.0, linear=True), waypoint(pulled + (0, 0, 0.1), qh, 1.0),
                waypoint(pos + (0, 0, 0.1), qb, 1.0), waypoint(pos, qb, 0.0), waypoint(pos + (0, 0, 0.25), qb, 0.0),
                waypoint(inside + (0, 0, 0.15), qd, 0.0), waypoint(inside, qd, 1.0)]

    def success(self):
        pos, _ = self.pose_of("block")
        k = self.variation
        dpos, dorn = self.pose_of("chest", chest.drawer_link(k))
        inv = p.invertTransform(dpos, dorn)
        local = np.array(p.multiplyTransforms(*inv, pos, (0, 0, 0, 1))[0])
        inside = 0.0 < local[0] < 0.22 and abs(local[1]) < 0.14 and 0.0 < local[2] < 0.08
        return bool(inside) and self.nothing_grasped()
