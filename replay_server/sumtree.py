"""A vectorised sum tree for proportional prioritised replay.

One flat float64 array holds a complete binary tree: node ``i`` has children ``2i`` and
``2i + 1``, the root is node 1 and the leaves are ``[L, 2L)`` for ``L`` a power of two.
Batch updates recompute the touched parents level by level from their children (never by
adding deltas), so sums cannot drift; batch queries descend all ``B`` queries together.
"""
from __future__ import annotations

import numpy as np


class SumTree:
    def __init__(self, capacity: int):
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.capacity = int(capacity)
        leaves = 1
        while leaves < capacity:
            leaves *= 2
        self._leaves = leaves
        self._tree = np.zeros(2 * leaves, dtype=np.float64)

    @property
    def total(self) -> float:
        return float(self._tree[1])

    def get(self, indices) -> np.ndarray:
        return self._tree[np.asarray(indices, dtype=np.int64) + self._leaves]

    def leaves(self) -> np.ndarray:
        """A copy of all priorities (length ``capacity``)."""
        return self._tree[self._leaves : self._leaves + self.capacity].copy()

    def set(self, indices, values) -> None:
        """Set priorities; with repeated indices the last value wins."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            return
        vals = np.broadcast_to(np.asarray(values, dtype=np.float64), idx.shape)
        if (idx < 0).any() or (idx >= self.capacity).any():
            raise IndexError("sum tree index out of range")
        if not np.isfinite(vals).all() or (vals < 0).any():
            raise ValueError("priorities must be finite and >= 0")
        self._tree[idx + self._leaves] = vals
        pos = np.unique((idx + self._leaves) // 2)
        while pos.size and pos[0] >= 1:
            self._tree[pos] = self._tree[2 * pos] + self._tree[2 * pos + 1]
            if pos[0] == 1:
                break
            pos = np.unique(pos // 2)

    def set_all(self, values: np.ndarray) -> None:
        """Replace every leaf (restore) and rebuild the tree bottom-up."""
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (self.capacity,):
            raise ValueError(f"expected {self.capacity} priorities, got {values.shape}")
        self._tree[:] = 0.0
        self._tree[self._leaves : self._leaves + self.capacity] = values
        level = self._leaves
        while level > 1:
            parents = np.arange(level // 2, level)
            self._tree[parents] = self._tree[2 * parents] + self._tree[2 * parents + 1]
            level //= 2

    def find(self, values: np.ndarray) -> np.ndarray:
        """Leaf index for each cumulative value in ``[0, total)``; never returns a zero leaf
        while the total is positive (rounding is steered away from empty subtrees)."""
        v = np.asarray(values, dtype=np.float64).copy()
        pos = np.ones(v.shape, dtype=np.int64)
        tree = self._tree
        while True:
            if pos.size == 0 or pos[0] >= self._leaves:
                break
            left = 2 * pos
            left_sum = tree[left]
            right = (v >= left_sum) & (tree[left + 1] > 0)
            right |= left_sum <= 0
            v = np.where(right, v - left_sum, v)
            pos = np.where(right, left + 1, left)
        return pos - self._leaves

    def sample(self, batch_size: int, rng: np.random.Generator) -> np.ndarray:
        """``batch_size`` i.i.d. leaves drawn with probability proportional to priority."""
        total = self.total
        if total <= 0:
            raise ValueError("no item has a positive priority")
        return self.find(rng.random(batch_size) * total)
