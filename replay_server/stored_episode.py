"""How an episode is kept in memory, and how an incoming one is packed into that form.

Each episode is kept whole: its ``T + 1`` observations are stored once, and transition ``t``
references observations ``t`` and ``t + 1`` of the same episode. Points may be narrowed to
float16 (``points_float16``) and large per-camera arrays (``*_rgb``, ``*_points``) compressed
per frame. A stored episode is never mutated after insertion, so snapshots and batch
gathering may hold references to its arrays without copying or locking.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocol.episode import Episode
from replay_server.frame_codec import FrameCodec

STEP_NAMES = ("actions", "rewards", "terminals", "policy_versions")
COMPRESSIBLE_SUFFIXES = ("_rgb", "_points")

#: observation name -> (stored dtype name, shape of one observation)
Schema = dict[str, tuple[str, tuple[int, ...]]]


@dataclass(eq=False)
class StoredEpisode:
    """One episode as kept in memory (immutable once inserted)."""

    serial: int  #: insertion order, unique within a store
    actor_id: str
    episode_id: int
    task: str
    seed: int
    is_demo: bool
    success: bool
    timeout: bool
    info: dict[str, str]
    num_steps: int
    arrays: dict[str, np.ndarray]  #: observation names (uncompressed) and "step/<name>" arrays
    frames: dict[str, list[bytes]]  #: compressed observation names: one blob per observation
    slots: np.ndarray  #: int64 [T]: the slot of transition t
    nbytes: int

    def meta(self) -> dict:
        return {
            "serial": self.serial,
            "actor_id": self.actor_id,
            "episode_id": self.episode_id,
            "task": self.task,
            "seed": self.seed,
            "is_demo": self.is_demo,
            "success": self.success,
            "timeout": self.timeout,
            "info": self.info,
            "num_steps": self.num_steps,
        }


def stored_dtype(name: str, array: np.ndarray, points_float16: bool) -> np.dtype:
    if name.endswith("_points") and points_float16 and array.dtype == np.float32:
        return np.dtype(np.float16)
    return array.dtype


def episode_schema(episode: Episode, points_float16: bool) -> Schema:
    """The observation arrays ``episode`` would be stored as (every episode of a store must match)."""
    return {
        name: (stored_dtype(name, a, points_float16).name, tuple(int(s) for s in a.shape[1:]))
        for name, a in sorted(episode.observations.items())
    }


def pack_episode(episode: Episode, serial: int, codec: FrameCodec, points_float16: bool) -> StoredEpisode:
    """``episode`` in its stored form (no slots yet: the ring assigns them)."""
    arrays: dict[str, np.ndarray] = {}
    frames: dict[str, list[bytes]] = {}
    nbytes = 0
    for name, a in episode.observations.items():
        dtype = stored_dtype(name, a, points_float16)
        if dtype != a.dtype:
            a = a.astype(dtype)
        if codec.enabled and name.endswith(COMPRESSIBLE_SUFFIXES):
            blobs = [codec.compress(f) for f in a]
            frames[name] = blobs
            nbytes += sum(len(b) for b in blobs)
        else:
            arrays[name] = a
            nbytes += a.nbytes
    for name in STEP_NAMES:
        a = getattr(episode, name)
        arrays["step/" + name] = a
        nbytes += a.nbytes
    return StoredEpisode(
        serial=serial,
        actor_id=episode.actor_id,
        episode_id=int(episode.episode_id),
        task=episode.task,
        seed=int(episode.seed),
        is_demo=bool(episode.is_demo),
        success=bool(episode.success),
        timeout=bool(episode.timeout),
        info=dict(episode.info),
        num_steps=episode.num_steps,
        arrays=arrays,
        frames=frames,
        slots=np.empty(0, dtype=np.int64),
        nbytes=nbytes,
    )
