"""Demonstrations on the robot (``c2farm robot-demos``): the operator's waypoints, recorded as MCAP demos.

The operator gives waypoints (a grasp-frame pose and the gripper after it, one per line, in the
terminal or a file); the arm executes each through the same ``RobotArm`` interface the actor
uses, while a recorder observes at a fixed rate. Each waypoint's end is a keyframe. The file is
the simulator's demo format (``actors.demos.mcap_io``), so the demo source sends it unchanged.

Joint velocities in the recorded frames are finite differences of the recorded joint positions:
the arm's own reading jitters at rest on franky-sim, and keyframe discovery looks for the arm
standing still exactly where the operator's waypoints end.

Waypoint lines: ``x y z [qx qy qz qw] open|close`` (metres, robot base frame; the default
orientation is top-down), ``#`` starts a comment.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from actors.demos.mcap_io import Demo
from actors.robot.interface import RobotArm
from protocol.observation import Observation

TOP_DOWN = (1.0, 0.0, 0.0, 0.0)


@dataclass
class Waypoint:
    """Where the grasp frame goes, then what the gripper does."""

    pose: np.ndarray  #: xyz + quaternion xyzw
    gripper_open: bool


def parse_waypoint(line: str) -> Waypoint | None:
    """One waypoint from ``x y z [qx qy qz qw] open|close``; None for a blank or comment line."""
    words = line.split("#", 1)[0].split()
    if not words:
        return None
    if words[-1] not in ("open", "close") or len(words) not in (4, 8):
        raise ValueError(f"waypoint {line.strip()!r}: expected 'x y z [qx qy qz qw] open|close'")
    numbers = [float(w) for w in words[:-1]]
    pose = np.array(numbers if len(numbers) == 7 else [*numbers, *TOP_DOWN], dtype=float)
    return Waypoint(pose, words[-1] == "open")


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
    ends: list[int] = []
    try:
        recorder.snap()
        for waypoint in waypoints:
            recorder.record(True)
            result = arm.move_to(waypoint.pose, waypoint.gripper_open)
            recorder.record(False)
            if not result.reached:
                break
            ends.append(recorder.snap())  # the arm stands still here: a keyframe
    finally:
        recorder.close()
    return Demo(task=task, seed=seed, success=len(ends) == len(waypoints), observations=recorder.frames,
                waypoint_frames=ends, control_hz=int(round(hz)))


def read_waypoints(lines) -> list[Waypoint]:
    """Every waypoint of a text (file or terminal), skipping blanks and comments."""
    return [wp for wp in (parse_waypoint(line) for line in lines) if wp is not None]


def record_demos(config, waypoints: list[Waypoint], episodes: int, out_dir, ask=input) -> list:
    """``episodes`` demos of ``waypoints`` on the configured arm, written as MCAP into ``out_dir``.

    Before each demo the operator sets the scene up and confirms (``ask``); a failed demo is
    not written and is tried again.
    """
    import contextlib
    from pathlib import Path

    from actors.demos.mcap_io import write_demo
    from actors.robot.actor import open_arm

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot = config.robot
    written = []
    with contextlib.ExitStack() as stack:
        arm, _ = open_arm(robot, stack)
        seed = len(list(out.glob("*.mcap")))
        while len(written) < episodes:
            arm.move_to(np.asarray(robot.home), gripper_open=True)
            ask(f"demo {len(written) + 1}/{episodes}: set the scene up, then press Enter ")
            demo = record_robot_demo(arm, waypoints, config.sim.task, seed)
            if not demo.success:
                print(f"demo failed at waypoint {len(demo.waypoint_frames) + 1}; again", flush=True)
                arm.recover()
                continue
            path = out / f"robot-{seed:04d}.mcap"
            write_demo(path, demo)
            written.append(path)
            seed += 1
            print(f"wrote {path} ({len(demo.observations)} frames)", flush=True)
    return written
