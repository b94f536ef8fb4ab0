"""What the replay's threads share: the store, its rate limiter and sampling RNG, the WAL,
the counters, and the two locks that order them.

``store_lock`` guards store, limiter and rng (held briefly by ingest, sampling and status);
``commit_lock`` orders WAL appends with inserts so that a checkpoint's snapshot and WAL
rotation describe the same point in time.
"""
from __future__ import annotations

import collections
import threading
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from replay_server.config import ReplayConfig
from replay_server.ratelimiter import RateLimiter
from replay_server.rejections import ReasonCounter
from replay_server.storage import EpisodeStore
from replay_server.wal import WriteAheadLog


@dataclass
class ReplayState:
    config: ReplayConfig
    store: EpisodeStore
    limiter: RateLimiter
    rng: np.random.Generator
    stats: collections.Counter = field(default_factory=collections.Counter)  #: every counter; saved in checkpoints
    info: dict[str, str] = field(default_factory=dict)  #: short strings for the status message
    store_lock: threading.Lock = field(default_factory=threading.Lock)
    commit_lock: threading.Lock = field(default_factory=threading.Lock)
    wal: Optional[WriteAheadLog] = None

    @classmethod
    def create(cls, config: ReplayConfig, seed: int) -> "ReplayState":
        limiter = RateLimiter(config.samples_per_insert, config.min_size_to_sample,
                              config.samples_per_insert_error_buffer, config.limit_inserts)
        return cls(config, EpisodeStore(config), limiter, np.random.default_rng(seed))

    def reasons(self, prefix: str, known: tuple[str, ...] = (), total: Optional[str] = None) -> ReasonCounter:
        """A by-reason counter writing into :attr:`stats` (so checkpoints and status carry it)."""
        return ReasonCounter(self.stats, prefix, known, total, self.config.reject_log_interval_s)
