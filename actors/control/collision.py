"""The planner's collision world: a second PyBullet DIRECT client mirroring robot, table and obstacles.

Planning teleports the arm thousands of times; doing it in the physics client would disturb the
simulation (PyBullet has one state per client, and resetting joints mid-step perturbs contacts), so
it happens here.
"""

from __future__ import annotations

import itertools

import numpy as np

from actors.sim.bullet import p
from actors.sim.scene import FINGER_JOINTS, GRASP_LINK, HOME, add_table, load_panda, set_arm

HAND_LINKS = {7, 8, 9, 10, 11}


class CollisionWorld:
    """Robot + table + the current task's obstacles; ``is_valid(q)`` is the OMPL state checker."""

    def __init__(self) -> None:
        self.client = p.connect(p.DIRECT)
        self.table = add_table(self.client)
        self.robot = load_panda(self.client)
        self.obstacles: list[int] = [self.table]
        self.ignored: set[tuple[int, int]] = set()  #: (body, link) parts that may be touched
        self.allowed: set[tuple[int, int, int]] = set()  #: (robot link, body, link) contacts exempted for one plan
        self.self_pairs = self._self_collision_pairs()
        self.checks = 0

    def _self_collision_pairs(self) -> set[tuple[int, int]]:
        """Non-adjacent link pairs not touching at HOME, hand/fingers excluded (ACM-style)."""
        set_arm(self.client, self.robot, HOME)
        links = range(-1, 12)
        pairs = set()
        for a, b in itertools.combinations(links, 2):
            if b - a <= 1 or (a in HAND_LINKS and b in HAND_LINKS):
                continue
            if not p.getClosestPoints(self.robot, self.robot, 0.0, a, b, physicsClientId=self.client):
                pairs.add((a, b))
        return pairs

    def set_obstacles(self, bodies: list[int], ignored: list[tuple[int, int]]) -> None:
        for b in self.obstacles[1:]:
            p.removeBody(b, physicsClientId=self.client)
        self.obstacles = [self.table, *bodies]
        self.ignored = set(ignored)

    def sync(self, sim_client: int, pairs: list[tuple[int, int]]) -> None:
        """Copy base poses and joint positions of (sim body, planner body) pairs into this world."""
        for sim_body, body in pairs:
            pos, orn = p.getBasePositionAndOrientation(sim_body, physicsClientId=sim_client)
            p.resetBasePositionAndOrientation(body, pos, orn, physicsClientId=self.client)
            for j in range(p.getNumJoints(sim_body, physicsClientId=sim_client)):
                q = p.getJointState(sim_body, j, physicsClientId=sim_client)[0]
                p.resetJointState(body, j, q, physicsClientId=self.client)

    def set_fingers(self, positions) -> None:
        """Open the fingers as wide as the real ones: the arm moves first and the gripper after
        (MoveArmThenGripper), so an open hand sweeps the scene open; left at the URDF's closed
        default, the planner would pass open fingers straight through the object they approach."""
        for j, v in zip(FINGER_JOINTS, positions):
            p.resetJointState(self.robot, j, float(v), 0.0, physicsClientId=self.client)

    def contacts(self, q) -> list[tuple[int, int, int]]:
        """Penetrating contacts (robot link, other body, other link) at ``q``; self pairs use body = robot."""
        set_arm(self.client, self.robot, q)
        p.performCollisionDetection(physicsClientId=self.client)
        found = []
        for c in p.getContactPoints(bodyA=self.robot, physicsClientId=self.client):
            if c[8] > 0.0:  # contact points come with a positive distance up to the threshold: not touching
                continue
            other, la, lb = c[2], c[3], c[4]
            if other == self.robot:
                if (min(la, lb), max(la, lb)) in self.self_pairs:
                    found.append((la, other, lb))
            elif other in self.obstacles and (other, lb) not in self.ignored:
                found.append((la, other, lb))
        return found

    def is_valid(self, q) -> bool:
        self.checks += 1
        return all(c in self.allowed for c in self.contacts(q))

    def fk(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Grasp-frame pose at ``q``."""
        set_arm(self.client, self.robot, q)
        s = p.getLinkState(self.robot, GRASP_LINK, computeForwardKinematics=True, physicsClientId=self.client)
        return np.array(s[4]), np.array(s[5])

    def close(self) -> None:
        if p.isConnected(self.client):
            p.disconnect(self.client)


