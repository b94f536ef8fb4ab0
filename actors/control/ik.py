"""Inverse kinematics for the grasp frame.

PyBullet's ``calculateInverseKinematics`` gives a starting guess but stalls at a few mm / 2 degrees
near the table, so the answer is refined with our own damped-least-squares iterations on the full
6-D error, verified by forward kinematics, and restarted from HOME and seeded random configurations
when it misses. The 7th degree of freedom is settled by a null-space pull: towards the current
configuration on the first try (the nearest solution, so a small Cartesian move is a small joint
move), towards HOME (away from the joint limits) on the restarts. Pulling towards HOME from the
current configuration drags the arm along its self-motion manifold and can land on a far-away
elbow/wrist configuration whose joint-space path sweeps the hand through nearby objects.
"""

from __future__ import annotations

import numpy as np

from actors.control.collision import CollisionWorld
from actors.control.limits import LOWER, UPPER
from actors.sim.bullet import p
from actors.sim.scene import GRASP_LINK, HOME, set_arm


def quaternion_angle(a, b) -> float:
    """Angle (rad) between two unit quaternions."""
    return float(2 * np.arccos(np.clip(abs(np.dot(a, b)), 0.0, 1.0)))


def orientation_error(target, current) -> np.ndarray:
    """Rotation vector taking ``current`` to ``target`` (world frame)."""
    inv = p.invertTransform((0, 0, 0), current)[1]
    dq = np.array(p.multiplyTransforms((0, 0, 0), target, (0, 0, 0), inv)[1])
    if dq[3] < 0:
        dq = -dq
    s = np.linalg.norm(dq[:3])
    return np.zeros(3) if s < 1e-12 else dq[:3] / s * 2 * np.arctan2(s, dq[3])


#: A refinement that has not cut its error by 1 % in 10 iterations is stuck: unreachable poses
#: used to spend all 100 iterations of every restart there (1.5 s per failed pose, BENCHMARKS.md).
STALL_EVERY, STALL_RATIO = 10, 0.99


class IKSolver:
    """Solves in the collision world's client so the physics is never touched."""

    def __init__(self, world: CollisionWorld, restarts: int = 24, position_tol: float = 0.002,
                 angle_tol: float = 0.02, iterations: int = 100) -> None:
        self.world, self.restarts, self.iterations = world, restarts, iterations
        self.position_tol, self.angle_tol = position_tol, angle_tol

    def _refine(self, q: np.ndarray, position, quaternion, rest: np.ndarray) -> tuple[np.ndarray, float, float]:
        client, robot = self.world.client, self.world.robot
        perr = aerr = np.inf
        checkpoint = np.inf  # the error STALL_EVERY iterations ago
        for i in range(self.iterations):
            pos, orn = self.world.fk(q)
            e = np.concatenate([position - pos, orientation_error(quaternion, orn)])
            perr, aerr = np.linalg.norm(e[:3]), np.linalg.norm(e[3:])
            if perr < self.position_tol * 0.25 and aerr < self.angle_tol * 0.25:
                break
            if i % STALL_EVERY == 0:
                err = perr / self.position_tol + aerr / self.angle_tol
                if err > STALL_RATIO * checkpoint:
                    break  # stuck in a local minimum (an unreachable pose): let the next restart try
                checkpoint = err
            jl, ja = p.calculateJacobian(robot, GRASP_LINK, (0, 0, 0), list(q) + [0.04, 0.04], [0.0] * 9, [0.0] * 9,
                                         physicsClientId=client)
            jac = np.vstack([np.array(jl)[:, :7], np.array(ja)[:, :7]])
            jjt = jac @ jac.T + (0.02 ** 2) * np.eye(6)
            pinv = jac.T @ np.linalg.inv(jjt)
            dq = pinv @ e + (np.eye(7) - pinv @ jac) @ (0.1 * (rest - q))
            step = np.abs(dq).max()
            if step > 0.3:
                dq *= 0.3 / step
            q = np.clip(q + dq, LOWER, UPPER)
        return q, perr, aerr

    def solve(self, position, quaternion, seed_q, accept=None, restarts: int | None = None) -> np.ndarray | None:
        """Joint positions within the Panda's limits that put the grasp frame at the pose, or None.

        ``accept(q)`` (e.g. collision-free) rejects a solution and moves on to the next restart.
        """
        position, quaternion = np.asarray(position, dtype=float), np.asarray(quaternion, dtype=float)
        rng = np.random.default_rng(0)  # deterministic restarts
        seeds = [np.asarray(seed_q, dtype=float)] + ([np.asarray(HOME)] if restarts != 0 else [])
        n = self.restarts if restarts is None else restarts
        # restarts spread out from HOME: uniform draws over the whole joint box mostly land in contortions
        seeds += [np.clip(np.asarray(HOME) + rng.normal(0.0, 0.3 + 1.2 * i / max(n, 1), 7), LOWER, UPPER)
                  for i in range(n)]
        ll, ul = list(LOWER) + [0, 0], list(UPPER) + [0.04, 0.04]
        ranges = [u - lo for lo, u in zip(ll, ul)]
        for i, seed in enumerate(seeds):
            rest = seeds[0] if i == 0 else np.asarray(HOME)  # nearest solution first, see the module docstring
            set_arm(self.world.client, self.world.robot, seed)
            guess = p.calculateInverseKinematics(
                self.world.robot, GRASP_LINK, list(position), list(quaternion), lowerLimits=ll, upperLimits=ul,
                jointRanges=ranges, restPoses=list(seed) + [0.04, 0.04], maxNumIterations=100,
                residualThreshold=1e-5, physicsClientId=self.world.client)
            for start in (np.clip(np.array(guess[:7]), LOWER, UPPER), seed):  # PyBullet's guess, else the seed itself
                q, perr, aerr = self._refine(start, position, quaternion, rest)
                if perr < self.position_tol and aerr < self.angle_tol:
                    if accept is None or accept(q):
                        return q
                    break
        return None
