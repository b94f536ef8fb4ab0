"""Keyframe (keypoint) discovery, exactly as ARM's ``keypoint_discovery`` (the authors' code).

A frame is a keyframe when the gripper opens or closes there, when it is the last frame, or when
the arm has "stopped" (all joint velocities within ``stopping_delta``, the gripper state steady
around it, at least 5 frames after the previous stop). The reference's quirks are kept on purpose,
including Python's negative indexing at frame 0, so our demos yield the reference's keyframes.

A demo that carries its operator's keyframes (robot demos) uses those instead: on a real arm
the rule also fires where the arm jitters or the operator pauses.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from protocol.observation import Observation

if TYPE_CHECKING:
    from protocol.episode_file import Demo


def _is_stopped(demo: Sequence[Observation], i: int, obs: Observation, stopped_buffer: int, delta: float) -> bool:
    next_is_not_final = i == (len(demo) - 2)
    gripper_state_no_change = i < (len(demo) - 2) and (
        obs.gripper_open == demo[i + 1].gripper_open
        and obs.gripper_open == demo[i - 1].gripper_open
        and demo[i - 2].gripper_open == demo[i - 1].gripper_open)
    small_delta = np.allclose(obs.joint_velocities, 0, atol=delta)
    return stopped_buffer <= 0 and small_delta and (not next_is_not_final) and gripper_state_no_change


def discover_keyframes(observations: Sequence[Observation], stopping_delta: float = 0.1) -> list[int]:
    """Indices of the keyframes of a demo recorded every control step."""
    keyframes: list[int] = []
    prev_gripper_open = observations[0].gripper_open
    stopped_buffer = 0
    for i, obs in enumerate(observations):
        stopped = _is_stopped(observations, i, obs, stopped_buffer, stopping_delta)
        stopped_buffer = 4 if stopped else stopped_buffer - 1
        last = i == (len(observations) - 1)
        if i != 0 and (obs.gripper_open != prev_gripper_open or last or stopped):
            keyframes.append(i)
        prev_gripper_open = obs.gripper_open
    if len(keyframes) > 1 and (keyframes[-1] - 1) == keyframes[-2]:
        keyframes.pop(-2)
    return keyframes


def demo_keyframes(demo: Demo) -> list[int]:
    """The keyframes a demo is learnt from: the operator's when it has them, else the reference rule's."""
    return list(demo.keyframes) if demo.keyframes is not None else discover_keyframes(demo.observations)
