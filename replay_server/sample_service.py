"""The ZeroMQ sample service: a ROUTER socket that serves batches and takes priority updates.

Requests wait (bounded: ``max_pending_requests`` in total, ``max_pending_per_client`` per
ZeroMQ identity) on the rate limiter and are served in order. A request larger than
``max_batch_size`` transitions or ``max_batch_bytes`` gets an error reply at once (the
learner's client raises ``ReplayError``: retrying would not help). Priority updates are
checked in full (lengths, finite and >= 0, indices in range) and applied whole or not at
all. Anything else is counted by reason as ``zmq_rejected_<reason>``; the loop itself
survives any exception (``zmq_error_<type>``).

With ``curve_certificate`` and ``curve_clients`` set the socket is a CURVE server: a ZAP
authenticator on the service's own context admits only the public keys in ``curve_clients``
(read at start). Failed handshakes (a plaintext client, an unknown key, a client that encrypts
for another server key) never reach the loop; a socket monitor counts them as
``zmq_rejected_auth`` (key refused) and ``zmq_rejected_handshake`` (anything else), logged at
most once per ``reject_log_interval_s`` each: a client with a wrong server key retries every
~100-200 ms. The per-client pending limit is then keyed by the client's public key (each
message's ``User-Id``), so reconnecting with new ZeroMQ identities does not get around it.
"""
from __future__ import annotations

import collections
import logging
import math
import threading
import time
from typing import Optional

import numpy as np
import zmq

from protocol import transition as tr
from protocol.codec import ProtocolError, peek_fields
from protocol.messages import PriorityUpdate, SampleBatch, SampleRequest, decode
from protocol.sample_wire import RETRY_PREFIX, batch_frames
from protocol.zmq_curve import (
    ZAP_DOMAIN,
    allowed_clients,
    describe_failure,
    drain_events,
    handshake_events,
    load_keypair,
)
from replay_server.rejections import protocol_reason
from replay_server.state import ReplayState
from replay_server.validation import decode_limits

log = logging.getLogger("replay_server")

REJECT_REASONS = ("frames", "decode", "kind", "batch_too_large", "batch_bytes_too_large", "pending_per_client",
                  "pending_total", "priorities_nonfinite", "priorities_negative", "priorities_length",
                  "priorities_range", "priorities_invalid", "auth", "handshake")
_PER_ITEM_EXTRA_BYTES = 64  # indices, keys, weights, probabilities, action, reward, flags


class SampleService:
    def __init__(self, state: ReplayState):
        self.state, self.config = state, state.config
        # decode refuses what is malformed; the limits we answer (batch size) are checked after it
        self.limits = decode_limits(self.config, max_bytes=self.config.max_request_bytes,
                                    max_batch=max(self.config.max_batch_size, 65536))
        self.rejected = state.reasons("zmq_rejected", REJECT_REASONS, total="zmq_rejected")
        self.errors = state.reasons("zmq_error", total="sample_errors")
        for name in ("batches_served", "sample_timeouts", "dropped_replies", "priority_updates_rejected"):
            state.stats.setdefault(name, 0)
        self._ctx: Optional[zmq.Context] = None
        self._sock: Optional[zmq.Socket] = None
        self._monitor: Optional[zmq.Socket] = None
        self._auth = None  # zmq.auth.thread.ThreadAuthenticator when CURVE is on
        self.curve = bool(self.config.curve_certificate)
        self._client_names: dict[str, str] = {}  # z85 public key -> key file name, for log lines
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._pending: collections.deque = collections.deque()
        self._per_client: collections.Counter = collections.Counter()
        self.endpoint = ""

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> str:
        cfg = self.config
        self._ctx = zmq.Context(io_threads=cfg.zmq_io_threads)
        sock = self._sock = self._ctx.socket(zmq.ROUTER)
        if self.curve:
            self._start_curve(sock)
        self._monitor = sock.get_monitor_socket(handshake_events())
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.SNDHWM, cfg.zmq_sndhwm)
        sock.setsockopt(zmq.RCVHWM, cfg.zmq_rcvhwm)
        sock.setsockopt(zmq.ROUTER_MANDATORY, 1)
        sock.setsockopt(zmq.MAXMSGSIZE, int(cfg.max_request_bytes))  # requests and updates are small
        sock.bind(cfg.zmq_endpoint)
        self.endpoint = sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._thread = threading.Thread(target=self._loop, name="replay-sampler", daemon=True)
        self._thread.start()
        return self.endpoint

    def _start_curve(self, sock: zmq.Socket) -> None:
        """CURVE server keys on ``sock`` and a ZAP authenticator (same context) admitting ``curve_clients``."""
        from zmq.auth.thread import ThreadAuthenticator

        cfg = self.config
        clients = allowed_clients(cfg.curve_clients)
        self._client_names = {key.decode(): name for key, name in clients.items()}
        self._auth = ThreadAuthenticator(self._ctx, log=logging.getLogger("replay_server.zap"))
        self._auth.start()
        # the domain must be the socket's zap_domain: pyzmq's "*" only matches sockets without one
        self._auth.configure_curve(domain=ZAP_DOMAIN, location=cfg.curve_clients)
        sock.curve_publickey, sock.curve_secretkey = load_keypair(cfg.curve_certificate)
        sock.curve_server = True
        sock.zap_domain = ZAP_DOMAIN.encode()
        log.info("sample service: CURVE on, %d allowed client key(s): %s", len(clients),
                 ", ".join(sorted(clients.values())))

    def close(self, timeout: float = 60.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.error("sampler thread did not stop within %.0f s", timeout)
        if self._sock is not None:
            if self._monitor is not None:
                self._sock.disable_monitor()
                self._monitor.close(linger=0)
            self._sock.close(linger=0)
        if self._auth is not None:
            self._auth.stop()
        if self._ctx is not None:
            self._ctx.term()

    @property
    def pending(self) -> int:
        return len(self._pending)

    # ------------------------------------------------------------------ loop
    def _loop(self) -> None:
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        poller.register(self._monitor, zmq.POLLIN)
        while not self._stop.is_set():
            try:
                if poller.poll(5 if self._pending else 100):
                    self._handshakes()
                    for _ in range(1024):
                        try:
                            frames = self._sock.recv_multipart(zmq.NOBLOCK, copy=False)
                        except zmq.Again:
                            break
                        try:
                            self._handle(frames)
                        except Exception as exc:  # this message only
                            self.errors.error(exc, "sample-service message")
                self._serve_pending()
            except Exception as exc:  # never let the loop die; back off a little
                self.errors.error(exc, "sample loop")
                time.sleep(0.01)

    def _handshakes(self) -> None:
        """Count the handshakes that failed since the last call (the monitor's events)."""
        for event, value in drain_events(self._monitor):
            if event != zmq.EVENT_HANDSHAKE_SUCCEEDED:
                reason, text = describe_failure(event, value)
                self.rejected.count(reason, text + " (the client got nothing)")

    def _client(self, ident: bytes, frame) -> tuple[object, str]:
        """Who sent ``frame``: the key of per-client limits, and a name for log lines ("" without CURVE).

        With CURVE it is the sender's public key (z85, from the authenticator), shown with its key file's name."""
        if not self.curve:
            return ident, ""
        try:
            key = frame.get("User-Id")
        except zmq.ZMQError:  # no user id: cannot happen after a CURVE handshake; keep the routing identity
            return ident, ""
        return key, f"{self._client_names.get(key, 'client')} (key {key[:8]}...)"

    def _handle(self, frames) -> None:
        client, who = self._client(frames[0].bytes, frames[-1])
        if len(frames) != 2:
            self.rejected.count("frames", f"{len(frames)} frames; a request is [identity, message]", sender=who)
            return
        ident, frame = frames[0].bytes, frames[1]
        try:
            msg = decode(frame.buffer, limits=self.limits)
        except ProtocolError as exc:
            self._refuse_undecodable(ident, frame.buffer, exc, who)
            return
        if isinstance(msg, SampleRequest):
            self._request(ident, client, msg, who)
        elif isinstance(msg, PriorityUpdate):
            self._priorities(msg, who)
        else:
            self.rejected.count("kind", f"unexpected {type(msg).__name__} on the sample service", sender=who)

    def _refuse_undecodable(self, ident: bytes, data, exc: ProtocolError, who: str = "") -> None:
        field = str(getattr(exc, "field", ""))
        if field in ("indices", "keys", "priorities"):
            text = str(exc)
            reason = ("priorities_nonfinite" if protocol_reason(exc) == "nonfinite"  # NaN, inf (or negative)
                      else "priorities_length" if "one length" in text
                      else "priorities_range" if ">= 0" in text else "priorities_invalid")
            self.state.stats["priority_updates_rejected"] += 1
        elif field == "batch_size" and self._peek_int(data, "batch_size") > self.config.max_batch_size:
            reason = "batch_too_large"
        else:
            reason = "decode"
        self.rejected.count(reason, str(exc), sender=who)
        self.state.info["last_zmq_rejection"] = str(exc)[:200]
        try:  # a request we could read the id of gets an answer, not a silent timeout
            rid = peek_fields(data).get("request_id")
        except Exception:
            return
        if isinstance(rid, int) and not isinstance(rid, bool) and 0 <= rid < 2**53:
            self._send(ident, SampleBatch(rid, {}, f"refused: {exc}", {}))

    @staticmethod
    def _peek_int(data, name: str) -> int:
        try:
            value = peek_fields(data).get(name)
        except Exception:
            return 0
        return value if isinstance(value, int) and not isinstance(value, bool) else 0

    # ------------------------------------------------------------------ requests
    def _request(self, ident: bytes, client, req: SampleRequest, who: str = "") -> None:
        """Queue ``req`` (answered to the routing identity ``ident``; ``client`` keys the per-client limit)."""
        cfg = self.config
        if req.batch_size > cfg.max_batch_size:
            self.rejected.count("batch_too_large", f"batch_size {req.batch_size} > max_batch_size={cfg.max_batch_size}",
                                sender=who)
            self._send(ident, SampleBatch(req.request_id, {}, f"refused: batch_size {req.batch_size} exceeds "
                                                             f"max_batch_size={cfg.max_batch_size}", {}))
            return
        nbytes = self._batch_bytes(req.batch_size)
        if nbytes > cfg.max_batch_bytes:
            self.rejected.count("batch_bytes_too_large", f"a batch of {req.batch_size} is ~{nbytes} bytes", sender=who)
            self._send(
                ident,
                SampleBatch(
                    req.request_id,
                    {},
                    f"refused: a batch of {req.batch_size} would be "
                    f"~{nbytes} bytes, more than max_batch_bytes={cfg.max_batch_bytes}",
                    {},
                ),
            )
            return
        if len(self._pending) >= cfg.max_pending_requests:
            self.rejected.count("pending_total", f"{len(self._pending)} requests waiting", sender=who)
            self._send(ident, SampleBatch(req.request_id, {}, f"{RETRY_PREFIX}: too many requests waiting", {}))
            return
        if self._per_client[client] >= cfg.max_pending_per_client:
            self.rejected.count("pending_per_client", f"client has {self._per_client[client]} requests waiting",
                                sender=who)
            self._send(
                ident,
                SampleBatch(req.request_id, {}, f"{RETRY_PREFIX}: too many requests waiting from this client", {}),
            )
            return
        wait = max(0.0, min(req.timeout_ms / 1000.0, cfg.sample_wait_timeout_s))
        self._per_client[client] += 1
        self._pending.append((ident, client, req, time.monotonic() + wait, wait))

    def _batch_bytes(self, batch_size: int) -> int:
        """Bytes a batch of ``batch_size`` gathers (t and t + 1 of every stored array), from the schema."""
        schema = self.state.store.schema
        if not schema:
            return 0
        per_item = sum(2 * math.prod(shape) * np.dtype(dtype).itemsize for dtype, shape in schema.values())
        return batch_size * (per_item + _PER_ITEM_EXTRA_BYTES)

    def _done(self, client) -> None:
        self._per_client[client] -= 1
        if self._per_client[client] <= 0:
            del self._per_client[client]

    def _serve_pending(self) -> None:
        now = time.monotonic()
        keep = collections.deque()
        blocked = False
        while self._pending:
            ident, client, req, deadline, wait = self._pending.popleft()
            try:
                served, reason = (False, "") if blocked else self._try_serve(ident, req)
            except Exception as exc:  # answer this request with the error, serve the rest
                self.errors.error(exc, "serving a batch")
                self._send(ident, SampleBatch(req.request_id, {}, f"internal error: {type(exc).__name__}", {}))
                self._done(client)
                continue
            if served:
                self._done(client)
                continue
            if reason:
                self.state.info["sample_wait"] = reason
                blocked = True  # serve in order
            if now >= deadline:
                with self.state.store_lock:
                    reason = reason or self.state.limiter.sample_block_reason(req.batch_size, self.state.store.size)
                self.state.stats["sample_timeouts"] += 1
                self._send(
                    ident, SampleBatch(req.request_id, {}, f"{RETRY_PREFIX}: no batch within {wait:.1f}s: {reason}", {})
                )
                self._done(client)
            else:
                keep.append((ident, client, req, deadline, wait))
        self._pending.extend(keep)

    def _try_serve(self, ident: bytes, req: SampleRequest) -> tuple[bool, str]:
        state, cfg = self.state, self.config
        with state.store_lock:
            reason = state.limiter.sample_block_reason(req.batch_size, state.store.size)
            if reason or state.store.size == 0:
                return False, reason or "the replay is empty"
            items = state.store.sample(req.batch_size, state.rng, cfg.importance_beta, cfg.demo_fraction)
            state.limiter.samples += req.batch_size
            info = self._batch_info(items.episodes)
        arrays = state.store.gather(items.episodes, items.ts)  # stored episodes are immutable: no lock needed
        arrays.update({tr.INDICES: items.slots, tr.KEYS: items.keys, tr.WEIGHTS: items.weights,
                       tr.PROBABILITIES: items.probabilities})
        self._send(ident, SampleBatch(req.request_id, arrays, "", info))
        state.stats["batches_served"] += 1
        return True, ""

    def _batch_info(self, episodes: list) -> dict[str, float]:
        """Scalars sent with a batch (the learner logs each as ``replay_<key>``)."""
        store, limiter = self.state.store, self.state.limiter
        return {
            "replay_size": float(store.size),
            "samples_per_insert": limiter.achieved(),
            "transitions_inserted": float(limiter.inserts),
            "demo_share": sum(ep.is_demo for ep in episodes) / max(1, len(episodes)),  # of this batch
        }

    def _send(self, ident: bytes, batch: SampleBatch) -> None:
        try:
            self._sock.send_multipart([ident] + batch_frames(batch), flags=zmq.NOBLOCK, copy=False)
        except (zmq.Again, zmq.ZMQError) as exc:  # learner gone or not reading: drop, it re-requests
            self.state.stats["dropped_replies"] += 1
            (log.warning if isinstance(exc, zmq.Again) else log.info)("batch reply dropped (%s)", exc)

    # ------------------------------------------------------------------ priorities
    def _priorities(self, msg: PriorityUpdate, who: str = "") -> None:
        """Apply an update only if all of it is sane; stale keys (overwritten slots) are normal."""
        idx, keys_, pri = msg.indices, msg.keys, msg.priorities
        reason, detail = "", ""
        arrays_ok = all(isinstance(a, np.ndarray) and a.ndim == 1 for a in (idx, keys_, pri))
        if not arrays_ok or not (idx.shape == keys_.shape == pri.shape):
            reason, detail = "priorities_length", "indices, keys and priorities must be 1-D of one length"
        elif idx.dtype.kind != "i" or keys_.dtype.kind != "i" or pri.dtype.kind != "f":
            reason, detail = "priorities_invalid", f"dtypes {idx.dtype}/{keys_.dtype}/{pri.dtype}"
        elif not np.isfinite(pri).all():
            reason, detail = "priorities_nonfinite", f"{int((~np.isfinite(pri)).sum())} non-finite priorities"
        elif (pri < 0).any():
            reason, detail = "priorities_negative", f"{int((pri < 0).sum())} negative priorities"
        elif len(idx) and (idx.min() < 0 or idx.max() >= self.state.store.capacity):
            reason, detail = "priorities_range", f"indices outside 0..{self.state.store.capacity - 1}"
        if reason:
            self.state.stats["priority_updates_rejected"] += 1
            self.rejected.count(reason, detail + " (update not applied)", sender=who)
            return
        with self.state.store_lock:
            self.state.store.update_priorities(idx, keys_, pri)
