"""The physical workspace: a Franka Panda on a table, in its own PyBullet DIRECT client.

The grasp frame is ``panda_grasptarget`` (link 11), the point between the finger pads; every pose
the agent talks about is that frame's. Grasping is RLBench's "fake grasp": closing the fingers
attaches a registered object that sits between them with a fixed constraint, opening releases it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet_data

from actors.sim import shapes
from actors.sim.bullet import p

ARM_JOINTS = tuple(range(7))
FINGER_JOINTS = (9, 10)
HAND_LINK = 8
GRASP_LINK = 11
#: The Panda "ready" pose; the grasp frame sits about 0.3 m in front of the base, 0.5 m up.
HOME = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)
ARM_FORCES = (87.0,) * 4 + (12.0,) * 3
FINGER_OPEN, FINGER_FORCE = 0.04, 40.0
TABLE_TOP_Z = 0.0


def add_table(client: int) -> int:
    """A plain box table whose top is the z = 0 plane; the robot base stands on it at the origin."""
    return shapes.box(client, (0.7, 0.75, 0.05), (0.35, 0.0, TABLE_TOP_Z - 0.05), rgba=(0.72, 0.6, 0.45, 1))


def load_panda(client: int, self_collision: bool = False) -> int:
    """The pybullet_data Panda with a fixed base at the origin, at HOME with open fingers."""
    p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
    flags = p.URDF_USE_SELF_COLLISION if self_collision else 0
    robot = p.loadURDF("franka_panda/panda.urdf", (0, 0, 0), useFixedBase=True, flags=flags,
                       physicsClientId=client)
    set_arm(client, robot, HOME, FINGER_OPEN)
    return robot


def set_arm(client: int, robot: int, q, fingers: float | None = None) -> None:
    """Teleport the arm (and optionally fingers) without dynamics."""
    for j, v in zip(ARM_JOINTS, q):
        p.resetJointState(robot, j, float(v), 0.0, physicsClientId=client)
    if fingers is not None:
        for j in FINGER_JOINTS:
            p.resetJointState(robot, j, fingers, 0.0, physicsClientId=client)


@dataclass
class Grasp:
    """An object held by the fake grasp."""

    body: int
    link: int
    constraint: int


class PandaScene:
    """Physics client, robot, table and gripper; tasks add their objects to ``client``."""

    def __init__(self, physics_hz: int = 240) -> None:
        self.client = p.connect(p.DIRECT)
        self.physics_hz = physics_hz
        p.setGravity(0, 0, -9.81, physicsClientId=self.client)
        p.setTimeStep(1.0 / physics_hz, physicsClientId=self.client)
        self.table = add_table(self.client)
        self.robot = load_panda(self.client)
        self.graspables: list[tuple[int, int]] = []  #: (body, link) pairs the gripper may attach
        self.grasped: Grasp | None = None
        self.gripper_open = 1.0
        self._q_prev = np.asarray(HOME, dtype=float)
        self.reset_robot()

    # ----- robot state ---------------------------------------------------------------------------
    def reset_robot(self, q=HOME) -> None:
        """Arm to ``q``, fingers open, nothing held, motors holding the pose."""
        self.release()
        set_arm(self.client, self.robot, q, FINGER_OPEN)
        self._q_prev = np.asarray(q, dtype=float)
        self.gripper_open = 1.0
        self.command(np.asarray(q), np.zeros(7))
        self._command_fingers(FINGER_OPEN)

    def _positions(self) -> np.ndarray:
        return np.array([s[0] for s in p.getJointStates(self.robot, ARM_JOINTS, physicsClientId=self.client)])

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Arm joint positions and velocities. Velocities are the motion over the last physics step:
        PyBullet's reported joint velocity under POSITION_CONTROL lags the actual motion, and keyframe
        discovery must see the arm stop exactly when it stops."""
        q = self._positions()
        return q, (q - self._q_prev) * self.physics_hz

    def finger_positions(self) -> np.ndarray:
        states = p.getJointStates(self.robot, FINGER_JOINTS, physicsClientId=self.client)
        return np.clip(np.array([s[0] for s in states]), 0.0, 0.04)

    def link_pose(self, link: int) -> tuple[np.ndarray, np.ndarray]:
        s = p.getLinkState(self.robot, link, computeForwardKinematics=True, physicsClientId=self.client)
        return np.array(s[4]), np.array(s[5])

    def grasp_pose(self) -> np.ndarray:
        """xyz + quaternion xyzw of the grasp frame, world."""
        pos, orn = self.link_pose(GRASP_LINK)
        return np.concatenate([pos, orn])

    # ----- actuation -----------------------------------------------------------------------------
    def command(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Joint position (+ feed-forward velocity) targets for the arm."""
        p.setJointMotorControlArray(self.robot, ARM_JOINTS, p.POSITION_CONTROL, targetPositions=list(q),
                                    targetVelocities=list(qd), forces=ARM_FORCES,
                                    positionGains=[0.3] * 7, velocityGains=[1.0] * 7,
                                    physicsClientId=self.client)

    def _command_fingers(self, target: float) -> None:
        p.setJointMotorControlArray(self.robot, FINGER_JOINTS, p.POSITION_CONTROL,
                                    targetPositions=[target] * 2, forces=[FINGER_FORCE] * 2,
                                    physicsClientId=self.client)

    def step(self, n: int = 1) -> None:
        for i in range(n):
            if i == n - 1:
                self._q_prev = self._positions()
            p.stepSimulation(physicsClientId=self.client)

    def actuate_gripper(self, open_: bool, max_time: float = 0.4) -> None:
        """Open or close the fingers until they settle; attach on close, release on open (RLBench)."""
        if open_:
            self.release()
        self._command_fingers(FINGER_OPEN if open_ else 0.0)
        self.gripper_open = 1.0 if open_ else 0.0
        steps, prev = int(max_time * self.physics_hz), self.finger_positions()
        for i in range(steps):
            self.step()
            now = self.finger_positions()
            if i > 0.06 * self.physics_hz and np.abs(now - prev).max() < 2e-5:
                break
            prev = now
        if not open_:
            self._attach_between_fingers()

    def _attach_between_fingers(self, tol: float = 0.004) -> None:
        for body, link in self.graspables:
            touching = [
                p.getClosestPoints(self.robot, body, tol, linkIndexA=f, linkIndexB=link, physicsClientId=self.client)
                for f in FINGER_JOINTS]
            if all(touching):
                self._attach(body, link)
                return

    def _attach(self, body: int, link: int) -> None:
        hand_pos, hand_orn = p.getLinkState(self.robot, GRASP_LINK, physicsClientId=self.client)[:2]
        if link == -1:
            obj_pos, obj_orn = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
        else:
            obj_pos, obj_orn = p.getLinkState(body, link, physicsClientId=self.client)[:2]
        inv_pos, inv_orn = p.invertTransform(hand_pos, hand_orn)
        rel_pos, rel_orn = p.multiplyTransforms(inv_pos, inv_orn, obj_pos, obj_orn)
        cid = p.createConstraint(self.robot, GRASP_LINK, body, link, p.JOINT_FIXED, (0, 0, 0), rel_pos,
                                 (0, 0, 0), parentFrameOrientation=rel_orn, physicsClientId=self.client)
        p.changeConstraint(cid, maxForce=300, physicsClientId=self.client)
        self.grasped = Grasp(body, link, cid)

    def release(self) -> None:
        if self.grasped is not None:
            p.removeConstraint(self.grasped.constraint, physicsClientId=self.client)
            self.grasped = None

    def is_grasped(self, body: int, link: int = -1) -> bool:
        return self.grasped is not None and (self.grasped.body, self.grasped.link) == (body, link)

    def close(self) -> None:
        if p.isConnected(self.client):
            p.disconnect(self.client)
