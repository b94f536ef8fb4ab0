"""Prioritised sampling over the stored items, in two tables (demo and agent).

Every occupied slot is an item with a priority and a unique, never reused ``key``, so a
priority update for a slot that has since been overwritten is ignored. New items get the
running maximum priority.

Two tables, demo and agent, share the slot space: each slot's priority also sits in the sum
tree of its episode's kind, so :meth:`PrioritisedTables.sample` can give demos a fixed share
of every batch (``demo_fraction``). Ten demos (~130 keyframe transitions) are ~1 % of a full
replay, so proportional sampling alone draws them into ~1 % of each batch. With
``demo_fraction = 0`` sampling is the reference's: one proportional distribution over every
item, from the combined tree.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Optional

import numpy as np

from replay_server.sumtree import SumTree


class PrioritisedDraw(NamedTuple):
    """Items drawn for one batch (arrays of length B, in draw order)."""

    slots: np.ndarray  #: int64: the slot of each item
    keys: np.ndarray  #: int64: each item's key, to send back with its new priority
    probabilities: np.ndarray  #: float32: P(i) within the table it was drawn from
    weights: np.ndarray  #: float32: importance weights, normalised by the batch max


class PrioritisedTables:
    def __init__(self, capacity: int, initial_priority: float, alpha: float, eps: float):
        self.capacity = capacity
        self.alpha, self.eps = alpha, eps
        self.tree = SumTree(capacity)  #: every item: the one-table (reference) distribution; what snapshots store
        #: (agent, demo): each slot's priority, in its kind's tree only
        self.tables = (SumTree(capacity), SumTree(capacity))
        self.slot_demo = np.zeros(capacity, dtype=bool)  #: which table a slot belongs to
        self.slot_key = np.full(capacity, -1, dtype=np.int64)  #: -1: an empty slot
        self.demo_size = 0  #: demo items
        self.agent_size = 0  #: agent (non-demo) items
        self.next_key = 0
        self.max_priority = float(initial_priority)

    def add(self, slots: np.ndarray, is_demo: bool, priorities=None, keys=None) -> None:
        """Make ``slots`` items of one episode: new ones (fresh keys, the running max priority),
        or, with ``priorities`` and ``keys``, restored ones."""
        n = len(slots)
        if keys is None:
            keys = np.arange(self.next_key, self.next_key + n, dtype=np.int64)
            self.next_key += n
        if priorities is None:
            priorities = np.full(n, self.max_priority)
        self.slot_key[slots] = keys
        self.slot_demo[slots] = is_demo
        if is_demo:
            self.demo_size += n
        else:
            self.agent_size += n
        self._set(slots, priorities)

    def remove(self, slots: np.ndarray, is_demo: bool) -> None:
        """``slots`` (one evicted episode's) hold no items any more."""
        self._set(slots, 0.0)
        self.slot_demo[slots] = False
        if is_demo:
            self.demo_size -= len(slots)
        else:
            self.agent_size -= len(slots)
        self.slot_key[slots] = -1

    def _set(self, slots: np.ndarray, values) -> None:
        """Write priorities to the combined tree and to each slot's own table."""
        slots = np.asarray(slots, dtype=np.int64).reshape(-1)
        values = np.broadcast_to(np.asarray(values, dtype=np.float64), slots.shape)
        self.tree.set(slots, values)
        demo = self.slot_demo[slots]
        for kind, tree in enumerate(self.tables):
            mask = demo == bool(kind)
            tree.set(slots[mask], values[mask])

    def demo_count(self, batch_size: int, demo_fraction: float) -> Optional[int]:
        """How many items of a batch come from the demo table; None: one table over everything.

        ``round(demo_fraction * batch_size)`` (halves up), but at least one item from each
        table when ``0 < demo_fraction < 1`` and the batch has room for both, so that neither
        kind silently vanishes from a small batch. None (the reference's one proportional
        table) when the fraction is 0 or either table has nothing to sample: a batch then
        comes from whatever exists.
        """
        if demo_fraction <= 0 or self.tables[0].total <= 0 or self.tables[1].total <= 0:
            return None
        if demo_fraction >= 1:
            return batch_size
        n = math.floor(demo_fraction * batch_size + 0.5)
        return min(max(n, 1), batch_size - 1) if batch_size >= 2 else n

    def sample(
        self, batch_size: int, rng: np.random.Generator, beta: float, demo_fraction: float = 0.0
    ) -> PrioritisedDraw:
        """Draw ``batch_size`` items.

        With a demo share (see :meth:`demo_count`) the first ``n_demo`` items come from the
        demo table and the rest from the agent table, each proportionally to priority within
        its table: ``P(i) = p_i / total of i's table`` and ``w = (N_table * P(i)) ** -beta``,
        normalised by the batch max. Otherwise one table over all ``N`` items (the reference).
        """
        n_demo = self.demo_count(batch_size, demo_fraction)
        if n_demo is None:
            slots = self.tree.sample(batch_size, rng)
            probs = self.tree.get(slots) / self.tree.total
            n_items = np.full(batch_size, float(max(1, self.demo_size + self.agent_size)))
        else:
            demo, agent = self.tables[1], self.tables[0]
            d_slots, a_slots = demo.sample(n_demo, rng), agent.sample(batch_size - n_demo, rng)
            slots = np.concatenate([d_slots, a_slots])
            probs = np.concatenate([demo.get(d_slots) / demo.total, agent.get(a_slots) / agent.total])
            n_items = np.repeat([float(self.demo_size), float(self.agent_size)], [len(d_slots), len(a_slots)])
        with np.errstate(divide="ignore"):
            w = np.power(n_items * probs, -beta) if beta else np.ones_like(probs)
        w = w / w.max()
        return PrioritisedDraw(
            slots.astype(np.int64), self.slot_key[slots].copy(), probs.astype(np.float32), w.astype(np.float32)
        )

    def update(self, indices: np.ndarray, keys: np.ndarray, priorities: np.ndarray) -> tuple[int, int]:
        """Apply updates whose key still matches the slot; returns (applied, stale)."""
        indices = np.asarray(indices, dtype=np.int64)
        keys = np.asarray(keys, dtype=np.int64)
        p = np.asarray(priorities, dtype=np.float64)
        in_range = (indices >= 0) & (indices < self.capacity)
        ok = in_range.copy()
        ok[in_range] = self.slot_key[indices[in_range]] == keys[in_range]
        ok &= self.slot_key[np.where(in_range, indices, 0)] >= 0
        ok &= np.isfinite(p) & (p >= 0)
        applied = int(ok.sum())
        if applied:
            vals = np.maximum(np.power(p[ok], self.alpha), self.eps)
            self._set(indices[ok], vals)
            self.max_priority = max(self.max_priority, float(vals.max()))
        return applied, len(indices) - applied
