"""The 11-value low-dimensional state of spec §1.

The time feature is computed from ``step`` = decisions already taken, for demos and live
episodes alike (DESIGN §4 fixes the reference's live-episode off-by-one, spec §10.4).
"""

from __future__ import annotations

import numpy as np
import torch

FINGER_MAX = 0.04  #: Panda finger joint range, metres


def time_feature(step, episode_length: int):
    """+1 at the first decision, -1 at decision ``episode_length - 1``."""
    return (1.0 - step / (episode_length - 1)) * 2.0 - 1.0


def proprioception(gripper_open, gripper_pose, finger_positions, step, episode_length: int, with_time: bool = True):
    """``[gripper_open(1), gripper_pose(7), fingers clipped to [0, 0.04](2), time(1)]`` -> float32[..., 11].

    ``with_time=False`` holds the time value at +1 (the first decision's) for every step: the
    state then names the keyframe by the gripper and the scene alone, so a policy one keyframe
    ahead of the demos (a skipped approach pose) still sees states the demos labelled.
    Accepts numpy arrays/scalars (returns numpy) or torch tensors (returns a tensor).
    """
    if not with_time:
        step = step * 0
    if isinstance(gripper_pose, torch.Tensor):
        dev = gripper_pose.device
        f = lambda x: torch.as_tensor(x, dtype=torch.float32, device=dev)  # noqa: E731
        g, pose, fing, t = f(gripper_open), f(gripper_pose), f(finger_positions), f(step)
        return torch.cat(
            [g[..., None], pose, fing.clamp(0.0, FINGER_MAX), time_feature(t, episode_length)[..., None]], -1
        )
    g = np.asarray(gripper_open, np.float32)
    pose = np.asarray(gripper_pose, np.float32)
    fing = np.clip(np.asarray(finger_positions, np.float32), 0.0, FINGER_MAX)
    t = time_feature(np.asarray(step, np.float32), episode_length).astype(np.float32)
    return np.concatenate([g[..., None], pose, fing, t[..., None]], -1).astype(np.float32)
