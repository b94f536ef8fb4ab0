"""RLBench-style cameras: render RGB + depth with TinyRenderer and lift depth to a world-frame cloud.

Conventions (protocol/observation.py): intrinsics K in pixels with the pixel *centre* of (u, v) at
integer coordinates, extrinsics camera-to-world in OpenCV axes (+z forward, +y down), so
``K @ inv(E)[:3] @ [p, 1] = depth * (u, v, 1)``. Points are unprojected from the linearised z-depth
with these very matrices, so projection and unprojection agree exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from actors.sim.bullet import p

NEAR, FAR = 0.01, 4.0
#: OpenGL camera axes (+y up, looking down -z) to OpenCV axes (+y down, looking down +z).
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class FixedCamera:
    """A camera fixed in the world, aimed from ``eye`` at ``target``."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)


#: Our stand-ins for RLBench's poses: across the table, and behind/above both robot shoulders.
FIXED_CAMERAS: dict[str, FixedCamera] = {
    "front": FixedCamera(eye=(1.45, 0.0, 0.75), target=(0.45, 0.0, 0.05)),
    "left_shoulder": FixedCamera(eye=(-0.15, 0.55, 0.75), target=(0.55, -0.1, 0.0)),
    "right_shoulder": FixedCamera(eye=(-0.15, -0.55, 0.75), target=(0.55, 0.1, 0.0)),
}
#: Wrist camera mount in the hand frame (panda_hand): a little behind the fingers, looking along tool z.
WRIST_OFFSET = (0.05, 0.0, 0.04)
WRIST_FOV_DEG = 70.0


def intrinsics(size: int, fov_deg: float) -> np.ndarray:
    """Pinhole K matching PyBullet's projection (vertical fov, square image)."""
    f = (size / 2.0) / np.tan(np.radians(fov_deg) / 2.0)
    c = size / 2.0 - 0.5
    return np.array([[f, 0, c], [0, f, c], [0, 0, 1]], dtype=np.float64)


def fixed_extrinsics(cam: FixedCamera) -> np.ndarray:
    """Camera-to-world (OpenCV axes) of a fixed camera."""
    view = np.array(p.computeViewMatrix(cam.eye, cam.target, cam.up)).reshape(4, 4, order="F")
    return np.linalg.inv(view) @ GL_TO_CV


def wrist_extrinsics(hand_pos, hand_orn) -> np.ndarray:
    """Camera-to-world of the wrist camera given the panda_hand link pose (moves with the hand)."""
    rot = np.array(p.getMatrixFromQuaternion(hand_orn)).reshape(3, 3)
    eye = np.asarray(hand_pos) + rot @ np.asarray(WRIST_OFFSET)
    e = np.eye(4)
    e[:3, 0], e[:3, 1], e[:3, 2] = rot[:, 1], -rot[:, 0], rot[:, 2]  # x right, y down, z along the fingers
    e[:3, 3] = eye
    return e


def render(client: int, extrinsics: np.ndarray, size: int, fov_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """RGB uint8 [H,W,3] and linear z-depth float32 [H,W] (metres along the optical axis)."""
    view = np.linalg.inv(extrinsics @ GL_TO_CV)  # world-to-GL-camera
    proj = p.computeProjectionMatrixFOV(fov_deg, 1.0, NEAR, FAR)
    _, _, rgba, zbuf, _ = p.getCameraImage(
        size, size, view.flatten(order="F").tolist(), proj, renderer=p.ER_TINY_RENDERER,
        flags=p.ER_NO_SEGMENTATION_MASK, physicsClientId=client)
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4)[:, :, :3].copy()
    zbuf = np.asarray(zbuf, dtype=np.float64).reshape(size, size)
    depth = FAR * NEAR / (FAR - (FAR - NEAR) * zbuf)
    return rgb, depth.astype(np.float32)
