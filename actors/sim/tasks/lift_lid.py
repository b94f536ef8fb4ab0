"""L3 lift_lid (take_lid_off_saucepan): grasp the small knob of a saucepan lid and lift the lid off.

RLBench's take_lid_off_saucepan has one variation, which C2F-ARM trains on: the saucepan and lid
look the same in every episode; only their place and yaw change.
"""

from __future__ import annotations

import numpy as np

from actors.sim import shapes
from actors.sim.bullet import p
from actors.sim.tasks.base import Task, top_down, waypoint

POT_R, POT_H = 0.08, 0.08
LID_T, KNOB = 0.01, (0.01, 0.012, 0.0125)  #: lid thickness, knob half extents


class LiftLid(Task):
    name = "lift_lid"
    obstacles = ("pot",)

    def sample(self, rng):
        self.position = np.array([rng.uniform(0.4, 0.6), rng.uniform(-0.2, 0.2), 0.0])
        self.yaw = rng.uniform(-np.pi / 4, np.pi / 4)
        self.colour = shapes.COLOURS["grey"]

    def spawn(self, client):
        x, y, _ = self.position
        orn = p.getQuaternionFromEuler((0, 0, self.yaw))
        pot = shapes.cylinder(client, POT_R, POT_H, (x, y, POT_H / 2), rgba=self.colour)
        lid = shapes.compound(client, [("cylinder", (POT_R + 0.005, LID_T), (0, 0, 0)),
                                       ("box", KNOB, (0, 0, LID_T / 2 + KNOB[2]))],
                              (x, y, POT_H + LID_T / 2), orn, rgba=(0.75, 0.75, 0.8, 1), mass=0.2)
        return {"pot": pot, "lid": lid}

    def graspables(self):
        return [(self.bodies["lid"], -1)]

    def knob_centre(self) -> np.ndarray:
        pos, _ = self.pose_of("lid")
        return pos + (0, 0, LID_T / 2 + KNOB[2] + 0.002)

    def waypoints(self):
        k = self.knob_centre()
        q = top_down(self.yaw)
        return [waypoint(k + (0, 0, 0.1), q, 1.0), waypoint(k, q, 0.0), waypoint(k + (0, 0, 0.2), q, 0.0)]

    def success(self):
        pos, _ = self.pose_of("lid")
        return self.scene.is_grasped(self.bodies["lid"]) and bool(pos[2] > POT_H + 0.1)
