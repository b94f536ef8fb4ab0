"""L1 push_button: press the cap of a spring button by 3 mm with the gripper closed, from above.

One look in every episode, as C2F-ARM trains on RLBench's variation 0 (a red button): the other
variations name their colour in language, which a C2F-ARM policy is never told.
"""

from __future__ import annotations

import numpy as np

from actors.sim import assets
from actors.sim.bullet import p
from actors.sim.tasks.base import Task, top_down, waypoint

CAP_TOP = 0.036  #: cap top height above the table at rest
PRESSED = -0.003  #: joint travel that counts as pressed


class PushButton(Task):
    name = "push_button"

    def sample(self, rng):
        self.position = np.array([rng.uniform(0.35, 0.6), rng.uniform(-0.2, 0.2), 0.0])
        self.yaw = rng.uniform(-np.pi / 4, np.pi / 4)

    def spawn(self, client):
        button = p.loadURDF(assets.path("button.urdf"), self.position, p.getQuaternionFromEuler((0, 0, self.yaw)),
                            useFixedBase=True, physicsClientId=client)
        p.setJointMotorControl2(button, 0, p.POSITION_CONTROL, targetPosition=0.0, force=4.0,
                                physicsClientId=client)  # the spring
        return {"button": button}

    def waypoints(self):
        q = top_down(self.yaw)
        x, y, _ = self.position
        return [waypoint((x, y, CAP_TOP + 0.06), q, 0.0), waypoint((x, y, CAP_TOP - 0.001), q, 0.0)]

    def success(self):
        return self.joint_position("button", 0) < PRESSED
