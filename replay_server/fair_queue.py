"""The ingest queue: one FIFO per sender, drained round-robin, bounded per sender and in total.

Zenoh delivers every episode to the replay through the one link to its router, so the
subscriber callback is effectively serial: if it waited on a queue that one flooding sender
had filled, every other sender would wait behind it. Hence a sender over its own quota is
refused at once (its episode is dropped unacked and the actor resends later), and only a
queue full across several senders makes the callback wait (bounded): that is ordinary
back-pressure, shared by everyone. Round-robin draining gives each sender with something
queued the same share of every ingest group.
"""
from __future__ import annotations

import collections
import threading
import time
from typing import Hashable

OK = ""
SENDER_QUOTA = "sender_quota"
BACKPRESSURE = "backpressure"


class FairQueue:
    def __init__(self, max_items: int, max_bytes: int, sender_items: int, sender_bytes: int):
        self.max_items, self.max_bytes = max(1, max_items), max(1, max_bytes)
        self.sender_items = max(1, min(sender_items, self.max_items))
        self.sender_bytes = max(1, min(sender_bytes, self.max_bytes))
        self._queues: "collections.OrderedDict[Hashable, collections.deque]" = collections.OrderedDict()
        self._sender_bytes: collections.Counter = collections.Counter()
        self._items = 0
        self._bytes = 0
        self.peak_items = 0
        self.peak_bytes = 0
        self._cond = threading.Condition()

    def __len__(self) -> int:
        return self._items

    @property
    def nbytes(self) -> int:
        return self._bytes

    @property
    def senders(self) -> int:
        return len(self._queues)

    def put(self, sender: Hashable, item, nbytes: int, timeout: float) -> str:
        """Queue ``item``; returns "" when queued, else why not (``sender_quota`` at once, or
        ``backpressure`` after waiting ``timeout`` seconds for room)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                q = self._queues.get(sender)
                mine = len(q) if q else 0
                if mine and (mine >= self.sender_items or self._sender_bytes[sender] + nbytes > self.sender_bytes):
                    return SENDER_QUOTA
                if not self._items or (self._items < self.max_items and self._bytes + nbytes <= self.max_bytes):
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    return BACKPRESSURE
                self._cond.wait(left)
            if q is None:
                q = self._queues[sender] = collections.deque()
            q.append((item, nbytes))
            self._sender_bytes[sender] += nbytes
            self._items += 1
            self._bytes += nbytes
            self.peak_items = max(self.peak_items, self._items)
            self.peak_bytes = max(self.peak_bytes, self._bytes)
            self._cond.notify_all()
            return OK

    def get_batch(self, max_items: int, timeout: float) -> list:
        """Up to ``max_items`` items, one per sender in turn; waits at most ``timeout`` for the first."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout)
            out = []
            while self._queues and len(out) < max_items:
                sender, q = self._queues.popitem(last=False)
                item, nbytes = q.popleft()
                self._sender_bytes[sender] -= nbytes
                self._items -= 1
                self._bytes -= nbytes
                out.append(item)
                if q:
                    self._queues[sender] = q  # back of the line
                else:
                    del self._sender_bytes[sender]
            if out:
                self._cond.notify_all()
            return out
