"""The observation every role agrees on: what a camera rig and a Panda report at one step.

Simulated actors, the real-robot bridge, demo files and replay batches all use this one
structure (flattened into named arrays on the wire, see ``episode.py``), so nothing needs
translating between roles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Camera names, as RLBench names them.
CAMERA_NAMES: tuple[str, ...] = ("front", "left_shoulder", "right_shoulder", "wrist")


@dataclass
class CameraFrame:
    """One camera's view, pixel-aligned: ``points[v, u]`` is the world point seen at ``rgb[v, u]``.

    Row 0 is the top of the image. ``intrinsics`` is the pinhole matrix K (pixels) and
    ``extrinsics`` the camera-to-world pose (OpenCV convention: +z forward, +y down), so
    ``K @ inv(extrinsics)[:3] @ [p, 1]`` projects a world point to ``(u, v, 1) * depth``.
    """

    rgb: np.ndarray  #: uint8 [H, W, 3]
    points: np.ndarray  #: float32 or float16 [H, W, 3], world frame, metres
    intrinsics: np.ndarray  #: float32 [3, 3]
    extrinsics: np.ndarray  #: float32 [4, 4], camera-to-world


def depth_to_points(depth: np.ndarray, k: np.ndarray, extrinsics: np.ndarray) -> np.ndarray:
    """World-frame organised cloud [H,W,3] float32: ``points[v,u]`` is the point seen at pixel (u,v)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = depth.astype(np.float64)
    cam = np.stack([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z], axis=-1)
    world = cam @ extrinsics[:3, :3].T + extrinsics[:3, 3]
    return world.astype(np.float32)


def camera_frame(rgb: np.ndarray, depth: np.ndarray, k: np.ndarray, extrinsics: np.ndarray) -> CameraFrame:
    """The CameraFrame of a camera's raw outputs: every world point from its depth, K and pose.

    Simulated cameras, real RGB-D cameras and the demo file reader all build frames here, so a
    reloaded or real frame unprojects exactly as the simulator's did.
    """
    k32, e32 = k.astype(np.float32), extrinsics.astype(np.float32)  # unproject with what is stored: reload is exact
    return CameraFrame(rgb=rgb, points=depth_to_points(depth, k32.astype(np.float64), e32.astype(np.float64)),
                       intrinsics=k32, extrinsics=e32)


@dataclass
class Observation:
    """Everything the policy, keyframe discovery and the replay need from one step."""

    cameras: dict[str, CameraFrame]
    gripper_pose: np.ndarray  #: float32 [7]: xyz + quaternion xyzw of the grasp frame, world
    gripper_open: float  #: 1.0 open, 0.0 closed
    finger_positions: np.ndarray  #: float32 [2]: the two finger joints, metres in [0, 0.04]
    joint_positions: np.ndarray  #: float32 [7]: arm joints, radians
    joint_velocities: np.ndarray  #: float32 [7]: arm joints, rad/s (keyframe discovery needs them)
    step: int = 0  #: decisions (next-best poses) taken before this observation
    extras: dict[str, np.ndarray] = field(default_factory=dict)  #: task-specific arrays, optional


#: Length of the action vector: xyz (3) + quaternion xyzw (4) + gripper open (1).
ACTION_SIZE = 8
