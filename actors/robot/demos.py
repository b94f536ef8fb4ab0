"""Demonstrations on the robot (``c2farm robot-demos``): the operator's waypoints, recorded as MCAP demos.

The operator gives waypoints (a grasp-frame pose and the gripper after it, one per line, in the
terminal or a file); the arm executes each through the same ``RobotArm`` interface the actor
uses, while a recorder observes at a fixed rate. The file is the simulator's demo format
(``protocol.episode_file``), so the demo source sends it unchanged.

Keyframes are where the operator says: each waypoint's end is one, except a via-point's (a
waypoint only there to steer the path, e.g. around an obstacle). They are stored in the demo
(``Demo.keyframes``) and the demo source uses them instead of discovering keyframes, which on a
real arm also fires on jitter and pauses.

Joint velocities in the recorded frames are finite differences of the recorded joint positions
(the arm's own reading jitters at rest on franky-sim), so the reference's keyframe discovery
still finds the waypoints' ends in files that predate operator keyframes.

Waypoint lines: ``x y z [qx qy qz qw] open|close [via]`` (metres, robot base frame; the default
orientation is top-down; a trailing ``via`` makes it a via-point), ``#`` starts a comment. The
last waypoint ends the demo, so it cannot be a via-point.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from actors.robot.interface import RobotArm, return_home
from protocol.episode_file import Demo
from protocol.observation import Observation

TOP_DOWN = (1.0, 0.0, 0.0, 0.0)
WAYPOINT_SYNTAX = "x y z [qx qy qz qw] open|close [via]"

log = logging.getLogger("robot.demos")


@dataclass
class Waypoint:
    """Where the grasp frame goes, then what the gripper does; a via-point's end is no keyframe."""

    pose: np.ndarray  #: xyz + quaternion xyzw
    gripper_open: bool
    keyframe: bool = True


def parse_waypoint(line: str) -> Waypoint | None:
    """One waypoint from ``x y z [qx qy qz qw] open|close [via]``; None for a blank or comment line."""
    words = line.split("#", 1)[0].split()
    if not words:
        return None
    via = words[-1] == "via"
    words = words[:-1] if via else words
    numbers = _finite_numbers(words[:-1])
    if not words or words[-1] not in ("open", "close") or numbers is None or len(numbers) not in (3, 7):
        raise ValueError(f"waypoint {line.strip()!r}: expected '{WAYPOINT_SYNTAX}'")
    pose = np.array(numbers if len(numbers) == 7 else [*numbers, *TOP_DOWN], dtype=float)
    return Waypoint(pose, words[-1] == "open", keyframe=not via)


def _finite_numbers(words: list[str]) -> list[float] | None:
    """The words as finite floats, or None if any is not one."""
    try:
        numbers = [float(w) for w in words]
    except ValueError:
        return None
    return numbers if all(np.isfinite(numbers)) else None


class Recorder:
    """Observes the arm every ``1 / hz`` seconds in its own thread while recording."""

    def __init__(self, arm: RobotArm, hz: float) -> None:
        self.arm, self.period = arm, 1.0 / hz
        self.frames: list[Observation] = []
        self._times: list[float] = []
        self._lock = threading.Lock()
        self._active = threading.Event()
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="demo-recorder", daemon=True)
        self._thread.start()

    def record(self, on: bool) -> None:
        with self._lock:  # a capture under way finishes first: nothing is added after record(False)
            (self._active.set if on else self._active.clear)()

    def snap(self) -> int:
        """Record one frame now (a keyframe); returns its index."""
        with self._lock:
            self._add(self.arm.observe(len(self.frames)))
            return len(self.frames) - 1

    def _run(self) -> None:
        while not self._closed.is_set():
            if self._active.wait(0.05):
                with self._lock:
                    if self._active.is_set() and not self._closed.is_set():
                        self._add(self.arm.observe(len(self.frames)))
                self._closed.wait(self.period)
        for camera in getattr(self.arm, "cameras", ()):
            getattr(camera, "release", lambda: None)()  # per-thread GL resources die with their thread

    def _add(self, obs: Observation) -> None:
        now = time.perf_counter()
        if self.frames:
            dt = max(now - self._times[-1], 1e-3)
            obs.joint_velocities = ((obs.joint_positions - self.frames[-1].joint_positions) / dt).astype(np.float32)
        else:
            obs.joint_velocities = np.zeros(7, np.float32)
        obs.step = len(self.frames)
        self.frames.append(obs)
        self._times.append(now)

    def close(self) -> None:
        self._closed.set()
        self._active.set()
        self._thread.join(timeout=5)


def record_robot_demo(arm: RobotArm, waypoints: list[Waypoint], task: str, seed: int, hz: float = 10.0) -> Demo:
    """Execute the waypoints and record them; a refused or failed waypoint ends the demo as unsuccessful."""
    recorder = Recorder(arm, hz)
    ends: list[int] = []  # where each waypoint reached so far ended
    try:
        recorder.snap()
        for waypoint in waypoints:
            recorder.record(True)
            result = arm.move_to(waypoint.pose, waypoint.gripper_open)
            recorder.record(False)
            if not result.reached:
                log.warning("demo of seed %d: waypoint %d %s (%s %s)", seed, len(ends) + 1, result.status,
                            result.reason, result.detail)
                break
            ends.append(recorder.snap())  # the arm stands still here
    finally:
        recorder.close()
    keyframes = [end for end, waypoint in zip(ends, waypoints) if waypoint.keyframe]
    return Demo(task=task, seed=seed, success=len(ends) == len(waypoints), observations=recorder.frames,
                waypoint_frames=ends, keyframes=keyframes, control_hz=int(round(hz)))


def read_waypoints(lines: Iterable[str]) -> list[Waypoint]:
    """Every waypoint of a text (file or terminal), skipping blanks and comments; ValueError on a bad one."""
    waypoints = [wp for wp in (parse_waypoint(line) for line in lines) if wp is not None]
    if waypoints and not waypoints[-1].keyframe:
        raise ValueError("the last waypoint ends the demo, so it is a keyframe: drop its 'via'")
    return waypoints


def record_demos(config, waypoints: list[Waypoint], episodes: int, out_dir, ask=input) -> list:
    """``episodes`` demos of ``waypoints`` on the configured arm, written as MCAP into ``out_dir``.

    Before each demo the operator sets the scene up and confirms (``ask``); a failed demo is
    not written and is tried again. With ``robot.scripted_operator`` (franky-sim) the scripted
    operator sets each scene up and gives the waypoints instead, seeded by the demo's number,
    and a failed demo starts franky-sim afresh: once its trajectory generator has refused a
    motion (seen on a busy machine), every later motion of that simulation failed too.
    """
    import contextlib
    from pathlib import Path

    from actors.robot.connect import open_arm
    from actors.robot.operator import OperatorChannel
    from actors.robot.reach_operator import ReachOperator
    from protocol.episode_file import write_demo

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot = config.robot
    written, failures = [], 0
    with contextlib.ExitStack() as stack:

        def start():
            arm, sim = open_arm(robot, stack)
            return arm, (ReachOperator(sim, OperatorChannel()) if robot.scripted_operator else None)

        arm, scripted = start()
        seed = len(list(out.glob("*.mcap")))
        while len(written) < episodes:
            home = return_home(arm, np.asarray(robot.home))
            demo = None
            if home.reached:
                if scripted is None:
                    ask(f"demo {len(written) + 1}/{episodes}: set the scene up, then press Enter ")
                plan = waypoints if scripted is None else scripted.demonstration(np.random.default_rng(seed))
                demo = record_robot_demo(arm, plan, config.sim.task, seed)
                demo.scene_bounds = robot.depth0_bounds  # the robot's box, not the simulated task's
            elif scripted is None:
                raise RuntimeError(f"the arm cannot reach its home pose: {home.reason} {home.detail}")
            if demo is None or not demo.success:
                where = "the home pose" if demo is None else f"waypoint {len(demo.waypoint_frames) + 1}"
                print(f"demo failed at {where}; again", flush=True)
                failures += 1
                if scripted is None:
                    arm.recover()
                    continue
                if failures > 3:  # no person to fix the scene: the same seed fails again
                    raise RuntimeError(f"the scripted demo of seed {seed} failed {failures} times")
                stack.close()  # franky-sim and the connection to it, then a fresh pair
                arm, scripted = start()
                continue
            path = out / f"robot-{seed:04d}.mcap"
            write_demo(path, demo)
            written.append(path)
            seed += 1
            print(f"wrote {path} ({len(demo.observations)} frames)", flush=True)
    return written
