"""RGB-D cameras of a robot rig: one contract, whatever the device.

A camera returns the simulator's ``CameraFrame``: square RGB, world-frame points (here the
world is the robot base frame), intrinsics K and camera-to-world extrinsics in OpenCV axes
(+z forward, +y down), exactly as ``protocol/observation.py`` documents. Depth is lifted to
points with ``protocol.observation.camera_frame``, the simulator's own unprojection, so a real
frame and a simulated one agree to the last bit on the maths.

Extrinsics come from a YAML file (by hand or a hand-eye calibration)::

    # camera-to-robot-base pose of the colour camera, OpenCV axes (+z forward, +y down)
    translation: [1.2, 0.0, 0.6]            # metres
    rotation_xyzw: [0.0, 0.87, -0.5, 0.0]   # unit quaternion
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
import yaml

from protocol.observation import CameraFrame, camera_frame


@runtime_checkable
class Camera(Protocol):
    """A calibrated RGB-D camera."""

    name: str

    def capture(self) -> CameraFrame:
        """One pixel-aligned RGB + world-point frame, taken now."""

    def close(self) -> None:
        """Release the device; safe to call twice."""


def load_extrinsics(path: str | Path) -> np.ndarray:
    """Camera-to-world 4x4 from a YAML file with ``translation`` and ``rotation_xyzw``."""
    data = yaml.safe_load(Path(path).read_text()) or {}
    try:
        t = np.asarray(data["translation"], dtype=float)
        q = np.asarray(data["rotation_xyzw"], dtype=float)
    except KeyError as exc:
        raise ValueError(f"{path}: missing key {exc} (need translation and rotation_xyzw)") from None
    if t.shape != (3,) or q.shape != (4,) or not np.all(np.isfinite(t)) or not np.all(np.isfinite(q)):
        raise ValueError(f"{path}: translation needs 3 numbers and rotation_xyzw 4")
    if abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise ValueError(f"{path}: rotation_xyzw is not a unit quaternion (norm {np.linalg.norm(q):.4f})")
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = quaternion_matrix(q / np.linalg.norm(q)), t
    return out


def save_extrinsics(path: str | Path, extrinsics: np.ndarray) -> None:
    """Write a camera-to-world pose in the format ``load_extrinsics`` reads."""
    q = matrix_quaternion(np.asarray(extrinsics, dtype=float)[:3, :3])
    text = ("# camera-to-robot-base pose of the colour camera, OpenCV axes (+z forward, +y down)\n"
            + yaml.safe_dump({"translation": [float(v) for v in extrinsics[:3, 3]],
                              "rotation_xyzw": [float(v) for v in q]}, default_flow_style=None))
    Path(path).write_text(text)


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_quaternion(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w, with w >= 0) of a rotation matrix."""
    w = np.sqrt(max(0.0, 1.0 + np.trace(r))) / 2.0
    x = np.copysign(np.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0, r[2, 1] - r[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0, r[0, 2] - r[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0, r[1, 0] - r[0, 1])
    q = np.array([x, y, z, w])
    return q / np.linalg.norm(q)


def square_frame(rgb: np.ndarray, depth: np.ndarray, k: np.ndarray, extrinsics: np.ndarray,
                 size: int) -> CameraFrame:
    """Centre-crop a device image to a square, resample it to ``size`` pixels, and lift it to a CameraFrame.

    Resampling is nearest-neighbour (a depth pixel is never a blend of two surfaces) and K follows
    the crop and the scale with pixel centres at integer coordinates, as the simulator's K does.
    Invalid depth (0, NaN: no return from the sensor) becomes NaN points, which voxelisation drops.
    """
    h, w = depth.shape
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    scale = size / side
    src = np.minimum(((np.arange(size) + 0.5) / scale).astype(int), side - 1)
    rows, cols = top + src, left + src
    rgb = np.ascontiguousarray(rgb[rows][:, cols, :3])
    z = depth[rows][:, cols].astype(np.float32)
    z[~np.isfinite(z) | (z <= 0)] = np.nan
    k2 = np.asarray(k, dtype=np.float64).copy()
    k2[0, 2] -= left
    k2[1, 2] -= top
    k2[0, 0] *= scale
    k2[1, 1] *= scale
    k2[0, 2] = (k2[0, 2] + 0.5) * scale - 0.5
    k2[1, 2] = (k2[1, 2] + 0.5) * scale - 0.5
    return camera_frame(rgb, z, k2, np.asarray(extrinsics, dtype=np.float64))
