"""The Franka Panda / FR3 through franky (libfranka): the robot interface on a real arm.

Poses go to the arm as franky ``CartesianMotion``s of the end-effector frame (the Franka
hand's TCP: the grasp frame) with scaled dynamics; the gripper opens with ``move`` and closes
with ``grasp`` (an empty close counts as done). Every pose passes the safety limits first.

franky-facts this relies on (franky-control 2.0, checked against franky-sim 1.0.4):

- ``Robot.stop()`` from another thread preempts a running ``move``, which then raises
  ``ControlException("... Move command preempted!")``; the arm holds where it is.
- A lost connection raises ``NetworkException`` and leaves that ``Robot`` unusable (every
  later call fails): recovery opens a new connection.
- Orientation quaternions are (x, y, z, w), as in the Observation.
- franky plans each motion with Ruckig and re-plans it every control tick; Ruckig can refuse a
  motion on a numerical edge (``RuntimeError("Motion planner failed with error code -111")``;
  -101, -110 alike), which the suite saw only on some hosts, where it refused the same move of
  fresh simulations four times running. ``recover_from_errors`` clears it and the same motion
  planned at other dynamics limits is a different numerical problem: hence ``replan_dynamics``.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np

from actors.robot.cameras import Camera
from actors.robot.config import FrankaConfig, SafetyConfig
from actors.robot.interface import MoveResult
from actors.robot.safety import Safety
from protocol.observation import Observation

log = logging.getLogger("robot.franka")

FINGER_MAX = 0.04  #: one finger's travel, metres (the Observation's finger_positions range)
OPEN_WIDTH = 2 * FINGER_MAX


class FrankaArm:
    """A Franka arm and gripper driven through franky, with cameras and safety limits."""

    def __init__(self, config: FrankaConfig, safety: SafetyConfig, cameras: list[Camera] | tuple = ()) -> None:
        self.config = config
        self.safety = Safety(safety)
        self.cameras = list(cameras)
        self._robot = self._gripper = None
        self._stopped = threading.Event()  # latched by stop(), cleared by resume()
        self._moving = threading.Lock()  # held while a move runs (stop() may come from another thread)
        self._gripper_open = True
        self.counters: dict[str, float] = {"moves": 0, "reached": 0, "failed": 0, "stops": 0, "recoveries": 0,
                                           "reconnects": 0, "unwinds": 0, "replans": 0}
        self.last_stop_s = float("nan")

    # -- connection --------------------------------------------------------------------

    def connect(self) -> None:
        import franky

        c = self.config
        self._robot = franky.Robot(c.host, relative_dynamics_factor=c.dynamics_factor,
                                   realtime_config=franky.RealtimeConfig.Ignore)
        self._robot.set_collision_behavior(c.torque_threshold, c.force_threshold)
        self._gripper = franky.Gripper(c.host)
        self._gripper_open = self._gripper.width > OPEN_WIDTH / 2
        log.info("connected to the Franka at %s (dynamics factor %.2f)", c.host, c.dynamics_factor)

    def disconnect(self) -> None:
        if self._robot is not None:
            try:
                self._robot.stop()
            except Exception as exc:  # already gone: nothing to stop
                log.debug("stop on disconnect: %s", exc)
        self._robot = self._gripper = None
        for camera in self.cameras:
            camera.close()

    # -- state -------------------------------------------------------------------------

    def joint_positions(self) -> np.ndarray:
        return np.asarray(self._robot.state.q, dtype=float)

    def grasp_pose(self) -> np.ndarray:
        """xyz + quaternion xyzw of the end-effector frame, robot base frame, from the measured joints.

        Computed from ``q`` with the robot's own model rather than read from ``O_T_EE``: franky-sim
        reports the desired pose there while the arm is idle.
        """
        import franky

        state = self._robot.state
        affine = self._robot.model.pose(franky.Frame.EndEffector, state.q, state.F_T_EE, state.EE_T_K)
        return np.concatenate([affine.translation, affine.quaternion]).astype(float)

    def observe(self, step: int = 0) -> Observation:
        frames = {camera.name: camera.capture() for camera in self.cameras}
        state = self._robot.state
        width = float(self._gripper.width)
        finger = np.clip(width / 2.0, 0.0, FINGER_MAX)
        return Observation(
            cameras=frames, gripper_pose=self.grasp_pose().astype(np.float32),
            gripper_open=1.0 if self._gripper_open else 0.0,
            finger_positions=np.array([finger, finger], dtype=np.float32),
            joint_positions=np.asarray(state.q, dtype=np.float32),
            joint_velocities=np.asarray(state.dq, dtype=np.float32), step=step)

    # -- motion ------------------------------------------------------------------------

    def move_to(self, pose: np.ndarray, gripper_open: bool) -> MoveResult:
        import franky

        t0 = time.perf_counter()
        if self._stopped.is_set():
            self.safety.refused["stopped"] += 1
            return MoveResult("refused", "stopped")
        pose = np.asarray(pose, dtype=float)
        reason = self.safety.check(pose, self.grasp_pose()[:3])
        if reason is not None:
            return MoveResult("refused", reason)
        self.counters["moves"] += 1
        position, quat = pose[:3], pose[3:] / np.linalg.norm(pose[3:])
        timings: dict[str, float] = {}
        with self._moving:
            try:
                if not self._already_at(position, quat):  # a null motion can fail the trajectory generator
                    if not self._plan_and_move(franky.Affine(position, quat)):
                        return self._failed("timeout", "", t0, timings)
                    self.wait_still(time.perf_counter(), timeout_s=self.config.settle_timeout_s)  # the arm lags
                timings["arm"] = time.perf_counter() - t0
                error = float(np.linalg.norm(self.grasp_pose()[:3] - position))
                if error > self.config.reach_tolerance:
                    return self._failed("not_reached", f"{error * 1000:.1f} mm from the target", t0, timings, error)
                t1 = time.perf_counter()
                if not self._set_gripper(gripper_open):
                    why = "stopped" if self._stopped.is_set() else "gripper_failed"
                    return self._failed(why, "", t0, timings, error)
                timings["gripper"] = time.perf_counter() - t1
            except franky.NetworkException as exc:
                return self._failed("connection_lost", str(exc), t0, timings)
            except (franky.ControlException, franky.CommandException, franky.GripperException, RuntimeError) as exc:
                why = "stopped" if self._stopped.is_set() else "control_error"
                return self._failed(why, str(exc), t0, timings)
        self.counters["reached"] += 1
        return MoveResult("reached", seconds=time.perf_counter() - t0, position_error=error, timings=timings)

    def _plan_and_move(self, target) -> bool:
        """Run a Cartesian motion to ``target``; False on a timeout (the arm stopped).

        A motion the trajectory generator refuses is planned again at the next, slower factor of
        ``replan_dynamics`` after clearing the arm's error; a refusal at the last factor is raised.
        """
        factors = self.config.replan_dynamics
        for factor, slower in zip(factors, factors[1:]):
            try:
                return self._move_once(target, factor)
            except RuntimeError as exc:  # franky's MotionPlannerException (a ControlException is not one)
                if "Motion planner failed" not in str(exc) or self._stopped.is_set():
                    raise
                log.warning("trajectory refused (%s): planning it again at %.2f of the dynamics", exc, slower)
                self.counters["replans"] += 1
                self._robot.recover_from_errors()
        return self._move_once(target, factors[-1])

    def _move_once(self, target, factor: float) -> bool:
        import franky

        self._robot.move(franky.CartesianMotion(target, relative_dynamics_factor=factor), asynchronous=True)
        if self._robot.join_motion(self.config.move_timeout_s):
            return True
        self._robot.stop()
        return False

    def _already_at(self, position: np.ndarray, quat: np.ndarray) -> bool:
        """Whether the grasp frame stands within a millimetre and half a degree of the target already.

        Ruckig, franky's trajectory generator, can reject a motion this short (synchronisation and
        duration errors -101/-110/-111), so such a move is not sent: the arm is where it was asked to be.
        """
        now = self.grasp_pose()
        angle = 2.0 * np.arccos(min(1.0, abs(float(np.dot(now[3:] / np.linalg.norm(now[3:]), quat)))))
        return float(np.linalg.norm(now[:3] - position)) < 1e-3 and np.degrees(angle) < 0.5

    def _set_gripper(self, want_open: bool) -> bool:
        c = self.config
        if want_open == self._gripper_open:
            return True
        if want_open:
            ok = self._gripper.move(OPEN_WIDTH, c.gripper_speed)
        else:  # closing on nothing is a finished close, not a failure: accept any final width
            ok = self._gripper.grasp(
                0.0, c.gripper_speed, c.gripper_force, epsilon_inner=0.005, epsilon_outer=OPEN_WIDTH
            )
        if ok:
            self._gripper_open = want_open
        return bool(ok)

    def _failed(self, reason: str, detail: str, t0: float, timings: dict, error: float = float("nan")) -> MoveResult:
        self.counters["failed"] += 1
        log.warning("move failed: %s %s", reason, detail)
        return MoveResult("failed", reason, detail, time.perf_counter() - t0, error, timings)

    # -- stop, resume, recover ---------------------------------------------------------

    def stop(self) -> float:
        """Preempt any motion and latch; return the seconds from the stop command until the arm stood still.

        "Still" is every joint slower than ``still_speed``, judged from joint positions 20 ms
        apart (franky-sim's reported joint velocities jitter at rest).
        """
        self._stopped.set()
        self.counters["stops"] += 1
        t0 = time.perf_counter()
        try:
            self._robot.stop()
            self._gripper.stop()
        except Exception as exc:  # a dead connection is stopped already; the latch still holds
            log.warning("stop: %s", exc)
            return float("nan")
        self.last_stop_s = self.wait_still(t0)
        return self.last_stop_s

    def wait_still(self, since: float, window_s: float = 0.02, timeout_s: float = 5.0) -> float:
        """Seconds from ``since`` until the joints moved less than ``still_speed * window_s`` in a window."""
        previous = self.joint_positions()
        while time.perf_counter() - since < timeout_s:
            time.sleep(window_s)
            now = self.joint_positions()
            if np.abs(now - previous).max() < self.config.still_speed * window_s:
                return time.perf_counter() - since - window_s  # still since the start of this window
            previous = now
        return float("nan")

    def resume(self) -> None:
        self._stopped.clear()

    @property
    def stopped(self) -> bool:
        return self._stopped.is_set()

    def unwind(self) -> bool:
        """``franka.home_joints`` by a joint motion: out of a twisted wrist or a posture where Cartesian moves fail."""
        import franky

        if self._stopped.is_set():
            return False
        self.counters["unwinds"] += 1
        with self._moving:
            try:
                self._robot.move(franky.JointMotion(np.asarray(self.config.home_joints)), asynchronous=True)
                if not self._robot.join_motion(self.config.move_timeout_s):
                    self._robot.stop()
                    return False
                self.wait_still(time.perf_counter(), timeout_s=self.config.settle_timeout_s)
            except (franky.NetworkException, franky.ControlException, franky.CommandException, RuntimeError) as exc:
                log.warning("unwind failed: %s", exc)
                return False
        return True

    def recover(self) -> bool:
        """Automatic error recovery; a lost connection is reopened. True when the arm accepts motions again."""
        import franky

        self.counters["recoveries"] += 1
        try:
            return bool(self._robot.recover_from_errors())
        except franky.NetworkException as exc:
            log.warning("connection lost (%s): reconnecting", exc)
        except Exception as exc:  # franky raises RuntimeError("Net Exception") on a dead connection too
            log.warning("recovery failed (%s): reconnecting", exc)
        try:
            self._robot = self._gripper = None
            self.connect()
            self.counters["reconnects"] += 1
            return True
        except Exception as exc:
            log.error("reconnect to %s failed: %s", self.config.host, exc)
            return False
