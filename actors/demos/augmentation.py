"""Demo augmentation (the authors' ARM code): one demo becomes several keyframe-to-keyframe episodes.

From every ``every_n``-th frame i, the agent "jumps" to each later keyframe in turn: obs(i) -> kf1 ->
... -> kf_last. The action of a step is the next keyframe's gripper pose + gripper state; the reward
is 0 except the last step (100, terminal). Step counters restart at 0 in every augmented episode so
the time feature matches live episodes (the reference's intent).

The chains repeat one another: from frame i past a keyframe, every jump but the first is one that frame 0's
chain already holds (the same observations; only the step counter differs). So a demo's later keyframes are
sampled as often as the augmented episodes that reach them, and its first ones rarely: put_item_in_drawer's
nine keyframes in ~160 frames give its first keyframe 5 % of a demo's transitions, against 25 % in
open_drawer's three keyframes in ~70 frames. ``chain_keyframes`` = k cuts each chain but frame 0's after its
first k jumps; a cut chain ends unfinished (no terminal, no reward), so the learner bootstraps its last jump
from the Q-values at the keyframe it reaches, as it does frame 0's. With k = 1 each distinct jump is stored
once, and a keyframe is sampled in proportion to the frames leading to it.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from protocol.observation import Observation

SUCCESS_REWARD = 100.0


@dataclass
class DemoEpisode:
    """A synthetic episode: T decisions, T+1 observations."""

    observations: list[Observation]  #: T+1, ``step`` = 0..T
    actions: np.ndarray  #: float32 [T, 8]: next keyframe's gripper_pose (7) + gripper_open (1)
    rewards: np.ndarray  #: float32 [T]
    terminals: np.ndarray  #: bool [T]


def keyframe_action(obs: Observation) -> np.ndarray:
    return np.concatenate([obs.gripper_pose, [obs.gripper_open]]).astype(np.float32)


def demo_to_transitions(observations: Sequence[Observation], keyframes: Sequence[int], every_n: int = 10,
                        augment: bool = True, success_reward: float = SUCCESS_REWARD,
                        chain_keyframes: int = 0) -> list[DemoEpisode]:
    """The augmented episodes of one demo (only the one from frame 0 when ``augment`` is False).

    ``chain_keyframes`` > 0 cuts every chain but frame 0's after that many jumps (0: never, as the authors).
    """
    episodes = []
    starts = range(0, len(observations) - 1, every_n) if augment else [0]
    for i in starts:
        remaining = [k for k in keyframes if k > i]
        if not remaining:
            break
        finished = i == 0 or not chain_keyframes or len(remaining) <= chain_keyframes
        if not finished:
            remaining = remaining[:chain_keyframes]
        frames = [i, *remaining]
        obs = []
        for t, f in enumerate(frames):
            o = copy.copy(observations[f])  # shallow: arrays shared, only the step counter differs
            o.step = t
            obs.append(o)
        actions = np.stack([keyframe_action(observations[k]) for k in remaining])
        n = len(remaining)
        rewards = np.zeros(n, dtype=np.float32)
        terminals = np.zeros(n, dtype=bool)
        if finished:
            rewards[-1] = success_reward
            terminals[-1] = True
        episodes.append(DemoEpisode(obs, actions, rewards, terminals))
    return episodes
