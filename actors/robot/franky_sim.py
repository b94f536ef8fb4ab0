"""franky-sim on loopback: a simulated Franka that speaks libfranka's real network protocol.

``FrankySim`` builds franky-sim's MuJoCo scene (the FR3 on the z = 0 table plane) plus a
reach task (a red target sphere, a mocap body with no collisions) and fixed RGB-D cameras,
binds the robot and gripper servers on a free loopback address, and steps the 1 kHz loop in a
background thread. ``franky.Robot(sim.hostname)`` then drives it exactly as a real arm.

Used by the tests, the benchmarks and ``c2farm robot --robot franky-sim``. Always a context
manager: the thread, the sockets and the MuJoCo state go away on exit, pass or fail.
"""

from __future__ import annotations

import logging
import threading
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from actors.robot.mujoco_camera import MujocoCamera, StateSnapshot

#: Where the fixed cameras look from and at (the PyBullet tasks' poses, so scene bounds carry over).
CAMERA_POSES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "front": ((1.45, 0.0, 0.75), (0.45, 0.0, 0.05)),
    "left_shoulder": ((-0.15, 0.55, 0.75), (0.55, -0.1, 0.0)),
    "right_shoulder": ((-0.15, -0.55, 0.75), (0.55, 0.1, 0.0)),
}
TARGET_RADIUS = 0.025


@dataclass
class SimSceneConfig:
    """What franky-sim's scene holds besides the arm."""

    target: tuple[float, float, float] = (0.5, 0.0, 0.2)  #: initial centre of the red reach target, metres
    cameras: tuple[str, ...] = ("front",)  #: fixed cameras to add, names from CAMERA_POSES
    fov_deg: float = 60.0  #: vertical field of view of the cameras, degrees (as the simulator's)
    snapshot_every: int = 10  #: physics steps between two state snapshots for the cameras (10 = every 10 ms)


class FrankySim:
    """franky-sim serving one FR3 (arm + gripper) on a loopback address, stepped in a thread."""

    def __init__(self, scene: SimSceneConfig | None = None, hostnames=None) -> None:
        self.scene = scene or SimSceneConfig()
        self._hostnames = hostnames
        self._sim = self._server = self._robot = None
        self._thread: threading.Thread | None = None
        self._closed = threading.Event()
        self._running = threading.Event()  # cleared while paused
        self._lock = threading.Lock()
        self._snapshot: StateSnapshot | None = None
        self._steps = 0
        self._next_tick: float | None = None
        self._cameras: list[MujocoCamera] = []

    # -- lifecycle ---------------------------------------------------------------------

    def start(self) -> "FrankySim":
        from franky_sim import SimulationServer
        from franky_sim.mujoco_simulator import MujocoSimulator

        logging.getLogger("franky_sim").setLevel(logging.WARNING)  # it logs every command at INFO
        self._sim = MujocoSimulator()
        self._sim.init()
        self._robot = self._sim.add_robot()
        self._add_task(self._sim.worldbody)
        self._sim.register_post_step_callback(self._after_step)
        kwargs = {} if self._hostnames is None else {"hostname_candidates": self._hostnames}
        self._server = SimulationServer(self._sim, **kwargs)
        self._server.init()  # binds the robot and gripper servers, builds the MuJoCo model
        self._take_snapshot()
        self._running.set()
        self._thread = threading.Thread(target=self._loop, name="franky-sim", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the loop, close the servers' sockets and the cameras; safe to call twice."""
        self._closed.set()
        self._running.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        for camera in self._cameras:
            camera.close()
        self._cameras.clear()
        if self._server is not None:
            self._server.cleanup()
            self._server = None
        if self._sim is not None and self._sim.is_initialized and not self._sim.is_cleaned_up:
            self._sim.cleanup()

    def __enter__(self) -> "FrankySim":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- what clients and tests see ----------------------------------------------------

    @property
    def hostname(self) -> str:
        """The loopback address to give ``franky.Robot`` / ``franky.Gripper``."""
        return self._robot.hostname

    def camera(self, name: str, size: int = 128) -> MujocoCamera:
        """A stand-in RGB-D camera rendering this scene from the fixed camera ``name``."""
        camera = MujocoCamera(name, self._sim.model, self.snapshot, f"cam_{name}", size)
        self._cameras.append(camera)
        return camera

    def snapshot(self) -> StateSnapshot:
        """Joint positions and mocap poses of the latest consistent instant (copies)."""
        with self._lock:
            qpos, mocap_pos, mocap_quat = self._snapshot
        return qpos.copy(), mocap_pos.copy(), mocap_quat.copy()

    @property
    def target(self) -> np.ndarray:
        """Centre of the reach target, metres, world frame."""
        return self.snapshot()[1][0].copy()

    def set_target(self, position) -> None:
        """Move the reach target (between two physics steps; cameras see it at once)."""
        with self._lock:
            self._sim.data.mocap_pos[0] = np.asarray(position, dtype=float)
            self._take_snapshot()

    def joint_positions(self) -> np.ndarray:
        """The arm's seven joint angles as the physics has them (ground truth, not via franky)."""
        qpos = self.snapshot()[0]
        return np.array([qpos[a] for a in self._robot._qpos_addrs])

    def sim_time(self) -> float:
        """Simulated seconds since start (it runs slower than the wall clock on a busy machine)."""
        return self._steps * 1e-3

    def pause(self, seconds: float) -> None:
        """Freeze the 1 kHz loop for ``seconds``, as a network drop would: no state reaches the client."""
        self._running.clear()
        try:
            self._closed.wait(seconds)
        finally:
            self._running.set()

    # -- internals ---------------------------------------------------------------------

    def _loop(self) -> None:
        while not self._closed.is_set():
            self._running.wait()
            if self._closed.is_set():
                return
            with self._lock:
                self._server.run_once(realtime=False)  # process commands, step, send state
            self._pace()

    def _pace(self) -> None:
        """Hold the 1 kHz rate against the wall clock (never faster than real time)."""
        now = time.perf_counter()
        self._next_tick = max((self._next_tick or now) + 1e-3, now - 0.01)  # fall behind at most 10 ms, never burst
        delay = self._next_tick - now
        if delay > 0:
            time.sleep(delay)

    def _after_step(self, _sim) -> None:
        self._steps += 1
        if self._steps % self.scene.snapshot_every == 0:
            self._take_snapshot()  # already under the lock: run_once holds it

    def _take_snapshot(self) -> None:
        d = self._sim.data
        self._snapshot = (d.qpos.copy(), d.mocap_pos.copy(), d.mocap_quat.copy())

    def _add_task(self, worldbody: ET.Element) -> None:
        target = ET.SubElement(worldbody, "body", name="target", mocap="true", pos=_vec(self.scene.target))
        ET.SubElement(target, "geom", name="target", type="sphere", size=str(TARGET_RADIUS), rgba="0.9 0.1 0.1 1",
                      contype="0", conaffinity="0")
        for name in self.scene.cameras:
            eye, look_at = CAMERA_POSES[name]
            ET.SubElement(worldbody, "camera", name=f"cam_{name}", pos=_vec(eye), xyaxes=_xyaxes(eye, look_at),
                          fovy=str(self.scene.fov_deg))


def _vec(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


def _xyaxes(eye, look_at) -> str:
    """MuJoCo camera axes (x right, y up, looking down -z) for a camera at ``eye`` aimed at ``look_at``."""
    forward = np.asarray(look_at, dtype=float) - np.asarray(eye, dtype=float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return _vec(np.concatenate([right, up]))
