"""The learner <-> replay ZeroMQ sample wire: batch frames, and the learner's pipelined client.

It lives in ``protocol/`` because two roles speak it: the replay server encodes batches
(:func:`batch_frames`) and the learner decodes them (:func:`parse_batch`,
:class:`ReplayClient`); roles meet only here and never import each other's packages.

Frames of one batch: ``[header, spec, array_0, array_1, ...]`` where ``header`` is
``protocol.messages.encode(SampleBatch(request_id, {}, error, info))`` (so version, kind and
fields are checked by the protocol codec), ``spec`` is JSON ``[[name, dtype, shape], ...]``
and each array frame is that array's raw little-endian C-order bytes. The server sends the
gathered arrays without serialising them (pyzmq ``copy=False``); the client wraps each frame
with ``np.frombuffer`` (read-only views, no copy). The single-frame safetensors encoding of
the protocol costs ~80 ms to encode and ~55 ms to decode a 38 MB B=128 batch here, which
is why batches travel this way; requests and priority updates keep the protocol codec.

``ReplayClient(endpoint, batch_size, prefetch=N)`` keeps ``N`` sample requests in flight, so
a batch is usually already waiting when the learner asks for the next one. Requests whose
answer never came (the server restarted) are forgotten after their own timeout plus a grace
period and re-issued. High-water marks bound the memory held in queues to about
``prefetch`` batches. The client needs numpy and pyzmq, never torch.

With ``curve_certificate`` (its own ``NAME.key_secret``) and ``curve_server_key`` (the replay's
public ``NAME.key``) the link is CURVE-encrypted and authenticated (``protocol.zmq_curve``). A
handshake that fails (key not allowed, wrong server key, one end plaintext) is only visible
in the socket's monitor events; the client watches them, and a :class:`ReplayTimeout` says
what failed, so a learner that cannot authenticate does not wait in silence.
"""
from __future__ import annotations

import itertools
import json
import math
import threading
import time

import numpy as np
import zmq

from protocol.codec import WIRE_DTYPES, ProtocolError, parse_json
from protocol.limits import DEFAULT_LIMITS
from protocol.messages import PriorityUpdate, SampleBatch, SampleRequest, decode, encode, validate
from protocol.zmq_curve import client_socket, describe_failure, drain_events, handshake_events

#: Prefix of a server error that means "try again" (rate limiter, queue full) rather than "refused".
RETRY_PREFIX = "rate limiter"


# ---------------------------------------------------------------------------- frames
def batch_frames(batch: SampleBatch) -> list:
    """The multipart frames of ``batch`` (arrays are passed as-is for a zero-copy send)."""
    header = encode(SampleBatch(batch.request_id, {}, batch.error, batch.info))
    names = list(batch.arrays)
    arrays = [np.ascontiguousarray(batch.arrays[n]) for n in names]
    spec = [[n, a.dtype.name, list(a.shape)] for n, a in zip(names, arrays)]
    return [header, json.dumps(spec).encode()] + arrays


def parse_batch(frames: list, max_bytes: int = 1 << 30) -> SampleBatch:
    """Validate and wrap the frames (``zmq.Frame`` or bytes) of one batch; raises ProtocolError only."""
    if len(frames) < 2:
        raise ProtocolError("batch", f"{len(frames)} frames; a batch has at least a header and a spec")
    buf = [f.buffer if hasattr(f, "buffer") else memoryview(f) for f in frames]
    total = sum(len(b) for b in buf)
    if total > max_bytes:
        raise ProtocolError("batch", f"{total} bytes exceeds the limit of {max_bytes}")
    head = decode(buf[0], expect=SampleBatch)
    if head.arrays:
        raise ProtocolError("batch", "arrays belong in their own frames")
    spec = parse_json(bytes(buf[1]), "batch.spec")  # depth-checked: no RecursionError from nesting
    if not isinstance(spec, list) or len(spec) != len(buf) - 2:
        raise ProtocolError("batch.spec", "malformed array spec or wrong number of frames")
    for entry, data in zip(spec, buf[2:]):
        if not (isinstance(entry, list) and len(entry) == 3):
            raise ProtocolError("batch.spec", f"bad entry {str(entry)[:80]!r}")
        name, dtype, shape = entry
        if (not isinstance(name, str) or name in head.arrays or not isinstance(shape, list)
                or len(shape) > DEFAULT_LIMITS.max_ndim
                or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s <= DEFAULT_LIMITS.max_dim
                           for s in shape)):
            raise ProtocolError("batch.spec", f"bad entry for {str(name)[:80]!r}")
        try:
            dt = np.dtype(dtype)
        except (TypeError, ValueError):
            raise ProtocolError(name, f"unknown dtype {str(dtype)[:40]!r}") from None
        if dt not in WIRE_DTYPES:
            raise ProtocolError(name, f"dtype {dt} cannot go on the wire")
        if math.prod(shape) * dt.itemsize != len(data):
            raise ProtocolError(name, f"{len(data)} bytes do not hold {dtype}{shape}")
        head.arrays[name] = np.frombuffer(data, dtype=dt.newbyteorder("<")).reshape(shape)
    validate(head)  # finiteness and bool bytes, as for every other message
    return head


# ---------------------------------------------------------------------------- client
class ReplayTimeout(TimeoutError):
    """No batch within the caller's timeout, or the server's rate limiter timed out (reason in the message)."""


class ReplayError(RuntimeError):
    """The server refused a request (e.g. batch larger than its ``max_batch_size``) or sent a malformed batch."""


class ReplayClient:
    """A torch-free, pipelined ZeroMQ DEALER client of the replay's sample service."""

    def __init__(
        self,
        endpoint: str,
        batch_size: int,
        prefetch: int = 2,
        request_timeout_s: float = 10.0,
        max_batch_bytes: int = 1 << 30,
        curve_certificate: str = "",
        curve_server_key: str = "",
        io_threads: int = 1,
    ):
        """``curve_certificate``/``curve_server_key``: key files for CURVE (both, or neither for
        plaintext); ``io_threads``: ZeroMQ I/O threads (CURVE decrypts in them)."""
        self.endpoint, self.batch_size = endpoint, int(batch_size)
        self.prefetch = max(1, int(prefetch))
        self.request_timeout_s = float(request_timeout_s)
        self.max_batch_bytes = max_batch_bytes
        if bool(curve_certificate) != bool(curve_server_key):
            raise ValueError("CURVE needs both curve_certificate and curve_server_key (or neither)")
        self.curve = bool(curve_certificate)
        self._ctx = zmq.Context(io_threads=max(1, int(io_threads)))
        self._sock = self._ctx.socket(zmq.DEALER)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.SNDHWM, 4 * self.prefetch + 64)
        self._sock.setsockopt(zmq.RCVHWM, self.prefetch + 1)
        self._sock.setsockopt(zmq.MAXMSGSIZE, int(max_batch_bytes) + (1 << 20))  # a huge reply drops the link
        if self.curve:
            client_socket(self._sock, curve_certificate, curve_server_key)
        self._monitor = self._sock.get_monitor_socket(handshake_events())
        self._sock.connect(endpoint)
        self._ids = itertools.count(1)
        self._in_flight: dict[int, float] = {}  # request id -> give-up time
        self.lost_requests = 0
        self.dropped_updates = 0
        self.handshakes = 0  #: handshakes completed (one per (re)connection)
        self.handshake_failures = 0  #: handshakes failed since the last one that completed
        self.last_handshake_failure = ""

    def _watch_handshakes(self) -> None:
        for event, value in drain_events(self._monitor):
            if event == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                self.handshakes += 1
                self.handshake_failures, self.last_handshake_failure = 0, ""
            else:
                self.handshake_failures += 1
                self.last_handshake_failure = describe_failure(event, value)[1]

    def _no_answer(self) -> str:
        """Why no answer came, as far as this end can tell (for the timeout message, one line)."""
        if self.handshake_failures:
            return (f"; the {'CURVE ' if self.curve else ''}handshake with the replay failed "
                    f"{self.handshake_failures} time{'s' * (self.handshake_failures != 1)} "
                    f"(last: {self.last_handshake_failure})")
        if self.curve and not self.handshakes:
            return ("; no answer and no CURVE handshake completed: the handshake may have failed (is this "
                    "learner's public key among replay.curve_clients, and curve_server_key the replay's key?)")
        return "; no answer from the server"

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

    def sample(self, timeout_s: float = 30.0, stop: threading.Event | None = None) -> SampleBatch:
        """The next batch (arrays are read-only zero-copy views; ``np.array(a)`` for a writable copy);
        raises :class:`ReplayTimeout` after ``timeout_s`` without one, or within 0.2 s of
        ``stop`` being set (a role told to stop must not wait out the timeout, or the
        launcher's grace ends first), and :class:`ReplayError` when refused.

        A request the server's rate limiter timed out is simply re-issued until ``timeout_s``
        has passed; the exception then carries the server's last reason."""
        deadline = time.monotonic() + timeout_s
        reason = ""
        while True:
            self._top_up()
            self._watch_handshakes()
            if stop is not None and stop.is_set():
                raise ReplayTimeout("stopped while waiting for a batch")
            left = deadline - time.monotonic()
            if left <= 0:
                raise ReplayTimeout(
                    f"no batch from {self.endpoint} within {timeout_s:.1f}s ({len(self._in_flight)} requests in flight)"
                    + (f"; server said: {reason}" if reason else self._no_answer())
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
            self._watch_handshakes()
            if batch.error:
                if batch.error.startswith(RETRY_PREFIX):
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
        if not self._sock.closed:
            self._sock.disable_monitor()
        self._monitor.close(linger=0)
        self._sock.close(linger=0)
        self._ctx.term()

    def __enter__(self) -> "ReplayClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
