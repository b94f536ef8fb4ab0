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
