"""Sampled (episode, t) pairs -> the batch arrays the learner trains on (1- or n-step transitions).

Runs without the store lock: stored episodes are immutable, and the codec keeps its
decompressors per thread.
"""
from __future__ import annotations

import numpy as np

from protocol import transition as tr
from replay_server.frame_codec import FrameCodec
from replay_server.stored_episode import Schema, StoredEpisode


def gather_transitions(
    episodes: list[StoredEpisode], ts: np.ndarray, schema: Schema, codec: FrameCodec, n_step: int
) -> dict[str, np.ndarray]:
    """Row ``i`` is transition ``ts[i]`` of ``episodes[i]``, named as ``protocol.transition`` says:
    every ``schema`` array as ``name`` (observation t) and ``next_name(name)`` (the one it leads to),
    then the step fields.

    With ``n_step`` = n > 1 each row is an n-step transition: the next observation is m =
    min(n, T - t) decisions later, ``n_rewards`` [B, n] the rewards in between (zeros past the
    episode's end), ``bootstrap_steps`` [B] that m, and ``terminal``/``timeout`` those of step
    t + m - 1; ``reward`` stays step t's own. The learner discounts with its gamma.
    """
    b = len(episodes)
    n = int(n_step)
    ts = np.asarray(ts, dtype=np.int64)
    steps = np.array([min(n, ep.num_steps - t) for ep, t in zip(episodes, ts)], dtype=np.int64)
    nxt_t = ts + steps
    last = nxt_t - 1  # the step whose terminal/timeout flags end this transition
    out: dict[str, np.ndarray] = {}
    for name, (dtype, shape) in schema.items():
        cur = np.empty((b,) + shape, dtype=dtype)
        nxt = np.empty((b,) + shape, dtype=dtype)
        if episodes[0].frames and name in episodes[0].frames:
            for i, (ep, t, t1) in enumerate(zip(episodes, ts, nxt_t)):
                blobs = ep.frames[name]
                codec.decompress_into(blobs[t], cur[i])
                codec.decompress_into(blobs[t1], nxt[i])
        else:
            for i, (ep, t, t1) in enumerate(zip(episodes, ts, nxt_t)):
                a = ep.arrays[name]
                cur[i] = a[t]
                nxt[i] = a[t1]
        out[name] = cur
        out[tr.next_name(name)] = nxt
    out[tr.ACTION] = np.stack([ep.arrays["step/actions"][t] for ep, t in zip(episodes, ts)])
    out[tr.REWARD] = np.array([ep.arrays["step/rewards"][t] for ep, t in zip(episodes, ts)], dtype=np.float32)
    out[tr.TERMINAL] = np.array([ep.arrays["step/terminals"][t] for ep, t in zip(episodes, last)], dtype=bool)
    out[tr.TIMEOUT] = np.array([ep.timeout and t == ep.num_steps - 1 for ep, t in zip(episodes, last)], dtype=bool)
    if n > 1:
        rewards = np.zeros((b, n), dtype=np.float32)
        for i, (ep, t, m) in enumerate(zip(episodes, ts, steps)):
            rewards[i, :m] = ep.arrays["step/rewards"][t : t + m]
        out[tr.N_REWARDS] = rewards
        out[tr.BOOTSTRAP_STEPS] = steps
    out[tr.POLICY_VERSION] = np.array(
        [ep.arrays["step/policy_versions"][t] for ep, t in zip(episodes, ts)], dtype=np.int64
    )
    out[tr.IS_DEMO] = np.array([ep.is_demo for ep in episodes], dtype=bool)
    return out
