"""The control agent (C2F-ARM phase 2): next-best pose -> IK -> plan -> Ruckig -> joint control -> gripper.

Any failure is an outcome, never an exception: an unreachable pose ends the episode (the actor's
caller turns it into reward 0, or -1 as the paper's option) but never the actor.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from actors.control.collision import CollisionWorld
from actors.control.ik import IKSolver
from actors.control.planner import MotionPlanner, Plan
from actors.control.trajectory import parameterise
from actors.sim.bullet import p
from actors.sim.scene import PandaScene

#: Why a pose could not be reached.
UNREACHABLE_REASONS = ("invalid_action", "out_of_workspace", "ik_failed", "planning_failed")


@dataclass
class ControlOutcome:
    """What happened to one next-best pose; ``timings`` in seconds per stage."""

    ok: bool
    reason: str | None = None  #: one of UNREACHABLE_REASONS when not ok
    timings: dict[str, float] = field(default_factory=dict)  #: ik, plan, trajectory, execute, gripper
    used_ompl: bool = False
    control_steps: int = 0
    path: np.ndarray | None = None

    @property
    def unreachable(self) -> bool:
        return not self.ok


@dataclass
class ControlConfig:
    """How poses are turned into joint motion."""

    planner: str = "RRTConnect"  #: OMPL planner name
    planning_time: float = 1.0  #: OMPL solve budget, CPU seconds of this process
    simplify_time: float = 0.1  #: path simplification budget, CPU seconds
    velocity_scale: float = 0.5  #: fraction of the Panda velocity limits
    acceleration_scale: float = 0.5  #: fraction of the Panda acceleration and jerk limits
    control_hz: int = 20  #: joint-controller rate; one control step = physics_hz / control_hz physics steps
    settle_time: float = 0.5  #: at most this long is spent converging on the final sample (within the last step)


class ControlAgent:
    """Owns the collision world; executes poses in a PandaScene."""

    def __init__(self, scene: PandaScene, config: ControlConfig | None = None, seed: int = 0) -> None:
        self.scene, self.config = scene, config or ControlConfig()
        self.world = CollisionWorld()
        self.ik = IKSolver(self.world)
        self.planner = MotionPlanner(self.world, self.config.planner, self.config.planning_time,
                                     self.config.simplify_time, seed)
        self.substeps = max(1, scene.physics_hz // self.config.control_hz)
        self._mirror: list[tuple[int, int]] = []
        self._reached: tuple[bytes, np.ndarray] | None = None  #: (pose + joints, IK goal) of the last reachable()

    def set_obstacles(self, spawn: Callable[[int], dict[str, int]], sim_bodies: dict[str, int], names, ignores) -> None:
        """Mirror the task's obstacles into the collision world (spawned there from the same parameters)."""
        self._reached = None  # a new scene: nothing solved before it holds
        mirrored = {n: b for n, b in spawn(self.world.client).items()}
        keep = {n: mirrored.pop(n) for n in names}
        for body in mirrored.values():
            p.removeBody(body, physicsClientId=self.world.client)
        self.world.set_obstacles(list(keep.values()), [(keep[n], link) for n, link in ignores if n in keep])
        self._mirror = [(sim_bodies[n], keep[n]) for n in keep]

    def execute(self, action: np.ndarray, workspace, on_step: Callable[[], None] | None = None,
                linear: bool = False) -> ControlOutcome:
        """MoveArmThenGripper: reach the grasp-frame pose ``action[:7]``, then open (>0.5) or close the gripper.

        ``linear`` moves the grasp frame along a straight Cartesian line (RLBench's "linear" waypoint
        extension, used by scripted demos that pull drawers), with IK at every centimetre.
        """
        on_step = on_step or (lambda: None)
        timings: dict[str, float] = {}
        action = np.asarray(action, dtype=float)
        pose, reason = self._target(action, workspace)
        if pose is None:
            return ControlOutcome(False, reason, timings)
        pos, quat, q0 = pose
        scene = self.scene

        t = time.perf_counter()
        path = self._linear_path(q0, pos, quat) if linear else None
        if path is not None:
            goal = path[-1]
        elif self._reached is not None and self._reached[0] == self._key(action, q0):
            goal = self._reached[1]  # reachable() just solved this very pose from this very state
        else:
            goal = self.ik.solve(pos, quat, q0, accept=self.world.is_valid)
        self._reached = None
        timings["ik"] = time.perf_counter() - t
        if goal is None:
            return ControlOutcome(False, "ik_failed", timings)

        t = time.perf_counter()
        plan = Plan(path, False, 0) if path is not None else self.planner.plan(q0, goal)
        timings["plan"] = time.perf_counter() - t
        if plan is None:
            return ControlOutcome(False, "planning_failed", timings)

        t = time.perf_counter()
        traj = parameterise(plan.path, self.config.velocity_scale, self.config.acceleration_scale)
        timings["trajectory"] = time.perf_counter() - t

        t = time.perf_counter()
        hz = scene.physics_hz
        dt = self.substeps / hz
        # Fixed-rate control steps, aligned so the last one ends exactly with the trajectory and the
        # remainder goes into the first one: the arm then reads as "stopped" only at the pose itself,
        # never one step early or just after it starts (keyframe discovery relies on this).
        n = max(1, int(np.floor(traj.duration / dt + 1e-9)))
        first = self.substeps + int(round((traj.duration - n * dt) * hz))
        t_sim = 0
        for k in range(1, n + 1):
            for _ in range(first if k == 1 else self.substeps):  # stream the trajectory at the physics rate
                t_sim += 1
                q, qd = traj.sample(t_sim / hz)
                scene.command(q, qd)
                scene.step()
            if k == n:
                self._settle(goal)
            on_step()
        timings["execute"] = time.perf_counter() - t

        t = time.perf_counter()
        want_open = action[7] > 0.5
        steps = n
        if want_open != (scene.gripper_open > 0.5):
            scene.actuate_gripper(want_open)
            on_step()
            steps += 1
        timings["gripper"] = time.perf_counter() - t
        return ControlOutcome(True, None, timings, plan.used_ompl, steps, plan.path)

    def reachable(self, action: np.ndarray, workspace, restarts: int = 4) -> bool:
        """Whether ``execute(action)`` would find a collision-free IK goal: IK only, no planning.

        Cheap (a few ms) because IK gets ``restarts`` restarts instead of 24; a pose that needs
        more is reported unreachable. The solution is kept, so executing this pose next
        reuses it rather than solving again (IK is deterministic, so it is the same goal).
        """
        action = np.asarray(action, dtype=float)
        pose, _ = self._target(action, workspace)
        if pose is None:
            return False
        pos, quat, q0 = pose
        goal = self.ik.solve(pos, quat, q0, accept=self.world.is_valid, restarts=restarts)
        if goal is not None:
            self._reached = (self._key(action, q0), goal)
        return goal is not None

    def _target(self, action: np.ndarray, workspace):
        """((position, unit quaternion, current joints), None) for a valid pose in the workspace, else (None, why).

        Also brings the collision world up to date with the scene, as IK checks against it.
        """
        if action.shape != (8,) or not np.all(np.isfinite(action)) or np.linalg.norm(action[3:7]) < 1e-6:
            return None, "invalid_action"
        pos, quat = action[:3], action[3:7] / np.linalg.norm(action[3:7])
        lo, hi = np.asarray(workspace[:3]), np.asarray(workspace[3:])
        if np.any(pos < lo) or np.any(pos > hi):
            return None, "out_of_workspace"
        q0, _ = self.scene.joint_state()
        self.world.sync(self.scene.client, self._mirror)
        self.world.set_fingers(self.scene.finger_positions())
        self.world.allowed = set(self.world.contacts(q0))
        return (pos, quat, q0), None

    @staticmethod
    def _key(action: np.ndarray, q0: np.ndarray) -> bytes:
        return action[:7].tobytes() + q0.tobytes()

    def _linear_path(self, q0: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> np.ndarray | None:
        """Joint path [N, 7] following the straight grasp-frame line, IK seeded from the previous point."""
        start_pos, start_orn = self.world.fk(q0)
        n = max(2, int(np.ceil(np.linalg.norm(pos - start_pos) / 0.01)) + 1)
        path, q = [q0], q0
        for s in np.linspace(0.0, 1.0, n)[1:]:
            orn = p.getQuaternionSlerp(start_orn, quat, s)
            q = self.ik.solve(start_pos + (pos - start_pos) * s, orn, q, accept=None, restarts=0)
            if q is None:
                return None
            path.append(q)
        return np.array(path)

    def _settle(self, goal: np.ndarray) -> None:
        """Hold the final sample until the arm has converged (part of the last control step)."""
        scene = self.scene
        scene.command(goal, np.zeros(7))
        for _ in range(int(self.config.settle_time * scene.physics_hz)):
            q, qd = scene.joint_state()
            if np.abs(q - goal).max() < 2e-3 and np.abs(qd).max() < 0.02:
                break
            scene.step()

    def close(self) -> None:
        self.world.close()
