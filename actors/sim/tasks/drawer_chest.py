"""The chest of drawers shared by open_drawer and put_item_in_drawer (assets/drawer_chest.urdf)."""

from __future__ import annotations

import numpy as np

from actors.sim import assets
from actors.sim.bullet import p
from actors.sim.tasks.base import yaw_rotate

DRAWERS = ("bottom", "middle", "top")
#: The drawer both tasks use: RLBench's variation 0 of open_drawer and put_item_in_drawer, the bottom one, which
#: C2F-ARM trains on (its demos are variation 0's). Drawn at random per episode (revisions 1-2), nothing in the
#: observation said which drawer to open: the greedy open_drawer policy opened the wrong one in nearly every
#: failed evaluation episode (its first pose 11-13 or 23 cm off, the drawers' spacing) and held at 35-55 %.
VARIATION = 0
DEPTH = 0.26  #: carcass depth along its x; the front face (with the handles) looks at -x
HANDLE_OFFSET = np.array([-0.035, 0.0, 0.055])  #: handle bar centre in its drawer's frame
SLOT_BOTTOM = (0.02, 0.14, 0.26)
#: The chest stands on (invisible) 5 cm legs: a bottom handle at table height is out of the hand's reach.
LEGS = 0.05


def drawer_link(k: int) -> int:
    return 2 * k


def handle_link(k: int) -> int:
    return 2 * k + 1


def spawn(client: int, position, yaw: float) -> int:
    chest = p.loadURDF(assets.path("drawer_chest.urdf"), position, p.getQuaternionFromEuler((0, 0, yaw)),
                       useFixedBase=True, physicsClientId=client)
    for k in range(3):
        # no motor: the drawers slide freely (damped), like RLBench's
        p.setJointMotorControl2(chest, drawer_link(k), p.VELOCITY_CONTROL, force=0.5, physicsClientId=client)
    return chest


def handle_position(position, yaw: float, k: int, opened: float = 0.0) -> np.ndarray:
    """World position of drawer ``k``'s handle bar centre when the drawer is pulled out by ``opened``."""
    local = np.array([-DEPTH / 2 - opened, 0.0, SLOT_BOTTOM[k]]) + HANDLE_OFFSET
    return np.asarray(position) + yaw_rotate(yaw, local)


#: Approach pitch: 40 degrees below horizontal. A level approach is out of the Panda's reach between
#: z = 0.25 and 0.4 m (its wrist joint 6 cannot bend back), tilted 40 degrees down it is reachable everywhere we
#: sampled.
APPROACH_PITCH = 0.72 * np.pi


#: How far in front of the handle the demos' approach keyframe stops, along the chest's -x. 10 cm: from 5 cm
#: (revision 2 of open_drawer, to bring the handle into the last depth's cube) or 7 cm the hand missed the handle
#: and left the bottom drawer shut in 9 and 17 of 100 scripted demos (100 of 100 from 10 cm). The grasp keyframe,
#: at the handle, is the one whose cube must see it, and does.
APPROACH_DISTANCE = 0.1


def handle_grasp_quaternion(yaw: float) -> np.ndarray:
    """Fingers pointing into the chest front (+x of the chest, tilted down), closing across the vertical bar."""
    q_yaw = p.getQuaternionFromEuler((0.0, 0.0, yaw))
    return np.array(
        p.multiplyTransforms((0, 0, 0), q_yaw, (0, 0, 0), p.getQuaternionFromEuler((0, APPROACH_PITCH, 0)))[1]
    )


def interior_centre(position, yaw: float, k: int, opened: float) -> np.ndarray:
    """World point at the middle of the part of drawer ``k`` that sticks out of the carcass."""
    local = np.array([-DEPTH / 2 - opened + opened / 2, 0.0, SLOT_BOTTOM[k] + 0.015])
    return np.asarray(position) + yaw_rotate(yaw, local)
