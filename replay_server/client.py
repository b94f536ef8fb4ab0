"""The learner's side of the sample service: a torch-free, pipelined ZeroMQ DEALER client.

``ReplayClient(endpoint, batch_size, prefetch=N)`` keeps ``N`` sample requests in flight, so
a batch is usually already waiting when the learner asks for the next one. Requests whose
answer never came (the server restarted) are forgotten after their own timeout plus a grace
period and re-issued. High-water marks bound the memory held in queues to about
``prefetch`` batches.
"""
from __future__ import annotations

import itertools
import time


import numpy as np
import zmq

from protocol.codec import ProtocolError
from protocol.messages import PriorityUpdate, SampleBatch, SampleRequest, encode
from replay_server.wire import parse_batch


class ReplayTimeout(TimeoutError):
    """No batch within the caller's timeout, or the server's rate limiter timed out (reason in the message)."""


class ReplayError(RuntimeError):
    """The server answered with an error other than a rate-limiter timeout."""


class ReplayClient:
    def __init__(
        self,
        endpoint: str,
        batch_size: int,
        prefetch: int = 2,
        request_timeout_s: float = 10.0,
        max_batch_bytes: int = 1 << 30,
    ):
        self.endpoint, self.batch_size = endpoint, int(batch_size)
        self.prefetch = max(1, int(prefetch))
        self.request_timeout_s = float(request_timeout_s)
        self.max_batch_bytes = max_batch_bytes
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.DEALER)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.SNDHWM, 4 * self.prefetch + 64)
        self._sock.setsockopt(zmq.RCVHWM, self.prefetch + 1)
        self._sock.connect(endpoint)
        self._ids = itertools.count(1)
        self._in_flight: dict[int, float] = {}  # request id -> give-up time
        self.lost_requests = 0
        self.dropped_updates = 0

    def _top_up(self) -> None:
        now = time.monotonic()
        for rid, give_up in list(self._in_flight.items()):
            if now > give_up:
                del self._in_flight[rid]
                self.lost_requests += 1
        while len(self._in_flight) < self.prefetch:
            rid = next(self._ids)
            req = SampleRequest(rid, self.batch_size, int(self.request_timeout_s * 1000))
            try:
                self._sock.send(encode(req), flags=zmq.NOBLOCK)
            except zmq.Again:
                return
            self._in_flight[rid] = now + self.request_timeout_s + 5.0

    def sample(self, timeout_s: float = 30.0) -> SampleBatch:
        """The next batch (arrays are read-only zero-copy views; ``np.array(a)`` for a writable copy);
        raises :class:`ReplayTimeout` after ``timeout_s`` without one.

        A request the server's rate limiter timed out is simply re-issued until ``timeout_s``
        has passed; the exception then carries the server's last reason."""
        deadline = time.monotonic() + timeout_s
        reason = ""
        while True:
            self._top_up()
            left = deadline - time.monotonic()
            if left <= 0:
                raise ReplayTimeout(
                    f"no batch from {self.endpoint} within {timeout_s:.1f}s ({len(self._in_flight)} requests in flight)"
                    + (f"; server said: {reason}" if reason else "; no answer from the server")
                )
            if not self._sock.poll(int(min(left, 0.2) * 1000) + 1, zmq.POLLIN):
                continue
            frames = self._sock.recv_multipart(copy=False)
            try:
                batch = parse_batch(frames, max_bytes=self.max_batch_bytes)
            except ProtocolError as exc:
                raise ReplayError(f"malformed batch from {self.endpoint}: {exc}") from None
            self._in_flight.pop(batch.request_id, None)
            self._top_up()
            if batch.error:
                if batch.error.startswith("rate limiter"):
                    reason = batch.error
                    continue
                raise ReplayError(batch.error)
            return batch

    def update_priorities(self, indices, keys, priorities) -> None:
        """Send new priorities (already raised to alpha); items overwritten since are ignored by the server."""
        msg = PriorityUpdate(
            np.asarray(indices, dtype=np.int64).reshape(-1),
            np.asarray(keys, dtype=np.int64).reshape(-1),
            np.asarray(priorities, dtype=np.float32).reshape(-1),
        )
        try:
            self._sock.send(encode(msg), flags=zmq.NOBLOCK)
        except zmq.Again:  # bounded queue full: priorities are soft state, dropping one update is safe
            self.dropped_updates += 1

    def close(self) -> None:
        self._sock.close(linger=0)
        self._ctx.term()

    def __enter__(self) -> "ReplayClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
