"""The ring of stored episodes: which slot holds which transition, and what is evicted next.

Transitions are *items*, one slot each; slot ``s`` holds transition ``slot_t[s]`` of the
episode with serial ``slot_serial[s]``. Capacity is bounded in transitions (slots) and in
bytes; when a new episode does not fit, the oldest episode is evicted first, agent episodes
before demos if ``keep_demos``. Free slots form a stack, so a fresh ring hands out 0, 1, 2...
Priorities are not kept here (see :mod:`replay_server.prioritised_tables`): the caller
clears the evicted episodes' slots there.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

from replay_server.stored_episode import StoredEpisode


class EpisodeRing:
    def __init__(self, capacity: int, capacity_bytes: int, keep_demos: bool):
        self.capacity = capacity
        self.capacity_bytes = capacity_bytes
        self.keep_demos = keep_demos
        self.episodes: dict[int, StoredEpisode] = {}  #: serial -> episode, in insertion order
        self.slot_serial = np.full(capacity, -1, dtype=np.int64)
        self.slot_t = np.zeros(capacity, dtype=np.int32)
        self.free = np.arange(capacity - 1, -1, -1, dtype=np.int64)  # a stack: pop from the end -> 0, 1, 2...
        self.n_free = capacity
        self.next_serial = 0
        self.bytes = 0
        self._fifo_live: OrderedDict[int, None] = OrderedDict()
        self._fifo_demo: OrderedDict[int, None] = OrderedDict()

    @property
    def size(self) -> int:
        """Stored transitions (occupied slots)."""
        return self.capacity - self.n_free

    def insert(self, stored: StoredEpisode) -> list[StoredEpisode]:
        """Give ``stored`` free slots, evicting the oldest episodes first as needed; returns the evicted."""
        t_steps = stored.num_steps
        evicted = []
        while self.n_free < t_steps or self.bytes + stored.nbytes > self.capacity_bytes:
            evicted.append(self._evict_one())
        stored.slots = self.free[self.n_free - t_steps : self.n_free][::-1].copy()
        self.n_free -= t_steps
        self._place(stored)
        return evicted

    def restore(self, episodes: list[StoredEpisode], free: np.ndarray) -> None:
        """Put back a snapshot's episodes (each in its recorded slots) and its free-slot stack."""
        for ep in episodes:
            self._place(ep)
        self.n_free = len(free)
        self.free[: self.n_free] = free

    def lookup(self, slots: np.ndarray) -> tuple[list[StoredEpisode], np.ndarray]:
        """The episode and transition index held by each of ``slots`` (all occupied)."""
        serials = self.slot_serial[slots]
        if (serials < 0).any():
            raise RuntimeError("sampled an empty slot")  # find() never returns a zero leaf
        return [self.episodes[int(s)] for s in serials], self.slot_t[slots].copy()

    def in_order(self) -> list[StoredEpisode]:
        """Every stored episode, oldest first (what a snapshot records)."""
        return [self.episodes[s] for s in sorted(self.episodes)]

    def _place(self, stored: StoredEpisode) -> None:
        slots = stored.slots
        self.next_serial = max(self.next_serial, stored.serial + 1)
        self.episodes[stored.serial] = stored
        (self._fifo_demo if stored.is_demo else self._fifo_live)[stored.serial] = None
        self.bytes += stored.nbytes
        self.slot_serial[slots] = stored.serial
        self.slot_t[slots] = np.arange(stored.num_steps, dtype=np.int32)

    def _evict_one(self) -> StoredEpisode:
        if self.keep_demos:
            fifo = self._fifo_live if self._fifo_live else self._fifo_demo
        else:
            heads = [f for f in (self._fifo_live, self._fifo_demo) if f]
            fifo = min(heads, key=lambda f: next(iter(f))) if heads else self._fifo_live
        if not fifo:
            raise RuntimeError("nothing left to evict")  # guarded by the store's check(): cannot happen
        serial, _ = fifo.popitem(last=False)
        ep = self.episodes.pop(serial)
        self.bytes -= ep.nbytes
        self.slot_serial[ep.slots] = -1
        self.free[self.n_free : self.n_free + len(ep.slots)] = ep.slots[::-1]
        self.n_free += len(ep.slots)
        return ep
