"""A stand-in RGB-D camera: renders franky-sim's MuJoCo scene offscreen (``MUJOCO_GL=egl``).

It keeps the RealSense contract (``cameras.Camera``): square RGB, world points, K and OpenCV
camera-to-world extrinsics. The simulator steps in its own thread at 1 kHz, so the camera never
reads its live data: it renders a private copy posed from the latest consistent snapshot of the
simulator state (joint positions and mocap poses), taken between two physics steps.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable

import numpy as np

from protocol.observation import CameraFrame

os.environ.setdefault("MUJOCO_GL", "egl")  # headless: before mujoco picks a GL backend

import mujoco  # noqa: E402  (after the GL backend is chosen)

from protocol.observation import camera_frame  # noqa: E402

#: MuJoCo camera axes (+y up, looking down -z) to OpenCV axes (+y down, looking down +z).
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])

#: (qpos, mocap_pos, mocap_quat) of one instant of the simulation.
StateSnapshot = tuple[np.ndarray, np.ndarray, np.ndarray]


class MujocoCamera:
    """Renders one named MuJoCo camera of a model from state snapshots."""

    def __init__(self, name: str, model: mujoco.MjModel, snapshot: Callable[[], StateSnapshot],
                 camera: str, size: int = 128) -> None:
        self.name = name
        self._model, self._snapshot, self._camera, self.size = model, snapshot, camera, size
        self._cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if self._cam_id < 0:
            raise ValueError(f"no camera {camera!r} in the MuJoCo model")
        self._data = mujoco.MjData(model)
        self._lock = threading.Lock()  # one posed copy of the scene, shared by the threads that capture
        self._local = threading.local()  # a renderer per capturing thread: a GL context is current in one thread
        self._renderers: list[mujoco.Renderer] = []
        f = (size / 2.0) / np.tan(np.radians(model.cam_fovy[self._cam_id]) / 2.0)
        c = size / 2.0 - 0.5  # pixel centres at integer coordinates, as the simulator's K
        self.intrinsics = np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])

    def capture(self) -> CameraFrame:
        qpos, mocap_pos, mocap_quat = self._snapshot()
        r = getattr(self._local, "renderer", None)
        if r is None:
            r = self._local.renderer = mujoco.Renderer(self._model, self.size, self.size)
            self._renderers.append(r)
        with self._lock:
            d = self._data
            d.qpos[:], d.mocap_pos[:], d.mocap_quat[:] = qpos, mocap_pos, mocap_quat
            mujoco.mj_forward(self._model, d)
            r.update_scene(d, camera=self._cam_id)
            rgb = r.render().copy()
            r.enable_depth_rendering()
            r.update_scene(d, camera=self._cam_id)
            depth = r.render().astype(np.float32)  # metres along the optical axis
            r.disable_depth_rendering()
            extrinsics = self.extrinsics()
        return camera_frame(rgb, depth, self.intrinsics, extrinsics)

    def extrinsics(self) -> np.ndarray:
        """Camera-to-world pose, OpenCV axes, from the posed copy of the scene."""
        pose = np.eye(4)
        pose[:3, :3] = self._data.cam_xmat[self._cam_id].reshape(3, 3)
        pose[:3, 3] = self._data.cam_xpos[self._cam_id]
        return pose @ GL_TO_CV

    def release(self) -> None:
        """Free the calling thread's renderer (call from a capturing thread before it ends)."""
        r = getattr(self._local, "renderer", None)
        if r is not None:
            self._local.renderer = None
            self._renderers.remove(r)
            r.close()

    def close(self) -> None:
        for r in self._renderers:
            try:
                r.close()
            except Exception:  # a context made current in a thread that is gone: the process frees it
                pass
        self._renderers.clear()
