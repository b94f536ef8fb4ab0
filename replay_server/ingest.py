"""Zenoh ingest: episodes in, each validated on its own, the good ones made durable and acked.

- Zenoh callback (never raises, never waits on one sender): checks the key's actor id and
  the source binding, then queues the payload in the per-sender :class:`FairQueue`.
- ingest thread: takes a round-robin group, validates every episode individually (a bad one
  is rejected and counted by reason; it never takes the rest of its group down), appends the
  good ones to the write-ahead log (one fsync), inserts them, then acks each to its actor.
  An ack therefore means "durable": a SIGKILL loses nothing acknowledged.

Acks are only published on ``acks/<id>`` for an id that passed ``keys.check_id`` and equals
the key the episode arrived on; an impersonation or a key/payload mismatch gets no ack at
all (an ack there would reach the real actor, who could take it for its own).
"""
from __future__ import annotations

import dataclasses
import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

import zenoh

from protocol import keys
from protocol.codec import ProtocolError, payload_digest, peek_fields
from protocol.episode import Episode
from protocol.messages import AckStatus, EpisodeAck, encode
from replay_server.fair_queue import BACKPRESSURE, OK, FairQueue
from replay_server.identity import SourceBindings, key_actor, source_zid
from replay_server.rejections import protocol_reason
from replay_server.state import ReplayState
from replay_server.validation import decode_episode, decode_limits

log = logging.getLogger("replay_server")

REJECT_REASONS = ("decode", "schema", "too_large", "bad_id", "nonfinite", "impersonation", "key_mismatch")
DROP_REASONS = ("sender_quota", "backpressure")
_HEAD_BYTES = 1 << 20  # what is kept of an oversized payload: enough to name its sender


@dataclass
class Received:
    """One payload as the callback queued it: who it came from, and its bytes (None: oversized)."""

    actor: str  #: checked actor id of the key expression
    zid: Optional[str]  #: Zenoh source session, when the publisher attached one
    raw: Optional[bytes]
    size: int
    head: bytes = b""  #: the start of an oversized payload
    digest: str = ""  #: payload_digest of the whole payload (every ack names it); set at once only when oversized

    def payload_digest(self) -> str:
        """Hashed on first use, in the ingest thread (not in Zenoh's callback)."""
        if not self.digest:
            self.digest = payload_digest(self.raw)
        return self.digest


@dataclass
class Accepted:
    episode: Episode
    item: Received
    digest: str


class Ingest:
    def __init__(self, state: ReplayState, session: zenoh.Session, run_id: str, on_wal_growth: Callable[[], None]):
        self.state, self.session, self.run_id = state, session, run_id
        self.config = cfg = state.config
        self._on_wal_growth = on_wal_growth
        self.queue = FairQueue(cfg.ingest_queue_size, cfg.ingest_queue_bytes,
                               cfg.ingest_sender_queue_size, cfg.ingest_sender_queue_bytes)
        self.bindings = SourceBindings(cfg.identity_bind_ttl_s, cfg.dedup_max_actors)
        self.limits = decode_limits(cfg)
        self._peek_limits = dataclasses.replace(self.limits, max_bytes=max(cfg.max_episode_bytes, _HEAD_BYTES))
        self.rejected = state.reasons("ingest_rejected", REJECT_REASONS, total="rejected")
        self.dropped = state.reasons("ingest_dropped", DROP_REASONS)
        self.errors = state.reasons("ingest_error", total="ingest_errors")
        self.callback_errors = state.reasons("callback_error", total="callback_errors")
        self.suspect = state.reasons("ingest_suspect", ("id_conflict",))
        self.ack_errors = state.reasons("ack_error", total="ack_failures")
        for name in ("duplicates", "dropped_backpressure", "insert_wait_timeouts"):
            state.stats.setdefault(name, 0)
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._subscriber = None
        self._liveliness = None
        state.stats.setdefault("identity_released", 0)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="replay-ingest", daemon=True)
        self._thread.start()
        self._subscriber = self.session.declare_subscriber(keys.episodes(self.run_id, "*"), self._on_sample)
        self._liveliness = self.session.liveliness().declare_subscriber(
            keys.alive(self.run_id, "actor", "*"), self._on_liveliness)

    def stop_receiving(self) -> None:
        if self._subscriber is not None:
            self._subscriber.undeclare()
            self._subscriber = None
        if self._liveliness is not None:
            self._liveliness.undeclare()
            self._liveliness = None

    def _on_liveliness(self, sample) -> None:
        """An actor's token went away: its id is free for the next session that claims it."""
        try:
            if sample.kind != zenoh.SampleKind.DELETE:
                return
            _, instance = keys.parse_role_instance(str(sample.key_expr))
            if self.bindings.release(instance):
                self.state.stats["identity_released"] += 1
        except Exception as exc:  # never raise into zenoh
            self.callback_errors.error(exc, "liveliness callback")

    def close(self, timeout: float = 60.0) -> None:
        """Stop receiving, then drain what is queued."""
        self.stop_receiving()
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.error("ingest thread did not stop within %.0f s", timeout)

    # ------------------------------------------------------------------ callback
    def _on_sample(self, sample) -> None:
        try:
            self._receive(sample)
        except Exception as exc:  # never raise into zenoh
            self.callback_errors.error(exc, "episode callback")

    def _receive(self, sample) -> None:
        try:
            actor = key_actor(sample.key_expr, self.run_id)
        except ValueError as exc:
            self.rejected.count("bad_id", str(exc))
            return
        zid = source_zid(sample)
        owner = self.bindings.owner(actor, zid)
        if owner is not None:
            self.rejected.count("impersonation", f"actor id {actor!r} is bound to session {owner}", sender=str(zid))
            return
        payload = sample.payload
        n = len(payload)
        if n > self.config.max_episode_bytes:
            whole = payload.to_bytes()  # hashed so the REJECTED ack names it; not kept
            item, size = Received(actor, zid, None, n, whole[:_HEAD_BYTES], payload_digest(whole)), _HEAD_BYTES
        else:
            item, size = Received(actor, zid, payload.to_bytes(), n), n
        result = self.queue.put(zid or actor, item, size, self.config.ingest_put_timeout_s)
        if result != OK:
            if result == BACKPRESSURE:
                self.state.stats["dropped_backpressure"] += 1
            self.dropped.count(result, f"episode dropped unacked (the actor resends): {len(self.queue)} queued",
                               sender=actor)

    # ------------------------------------------------------------------ ingest thread
    def _loop(self) -> None:
        while True:
            items = self.queue.get_batch(self.config.ingest_batch_max, timeout=0.1)
            if not items:
                if self._stop.is_set():
                    return
                continue
            try:
                self._ingest(items)
            except Exception as exc:  # e.g. the WAL's disk: nothing of the group was acked
                self.errors.error(exc, f"ingest of {len(items)} episodes (not acked; actors resend)")

    def _ingest(self, items: list[Received]) -> None:
        acks: list[EpisodeAck] = []
        accepted: list[Accepted] = []
        seen: set = set()
        for item in items:
            try:
                ok = self._admit(item, seen, acks)
            except Exception as exc:  # one message's surprise is that message's problem only
                self.errors.error(exc, f"episode from {item.actor}")
                continue
            if ok is not None:
                accepted.append(ok)
        if accepted:
            self._commit(accepted, acks)
        for ack in acks:
            self._publish_ack(ack)

    def _admit(self, item: Received, seen: set, acks: list) -> Optional[Accepted]:
        cfg, state = self.config, self.state
        if item.raw is None:
            self._reject(
                item,
                "too_large",
                f"message of {item.size} bytes exceeds max_episode_bytes={cfg.max_episode_bytes}",
                acks,
            )
            return None
        try:
            ep = decode_episode(item.raw, cfg, self.limits)
        except ProtocolError as exc:
            self._reject(item, protocol_reason(exc), str(exc), acks)
            return None
        if ep.actor_id != item.actor:
            self.rejected.count("key_mismatch", f"episode of {ep.actor_id[:130]!r} on the key of {item.actor!r}",
                                sender=item.actor)
            return None
        digest = item.payload_digest()
        with state.store_lock:
            dup = state.store.is_duplicate(ep.actor_id, ep.episode_id, digest)
            conflict = not dup and state.store.is_id_conflict(ep.actor_id, ep.episode_id, digest)
            reason = "" if dup else state.store.check(ep)
        if dup or (ep.key, digest) in seen:
            state.stats["duplicates"] += 1
            acks.append(EpisodeAck(ep.actor_id, ep.episode_id, AckStatus.DUPLICATE, digest=digest))
            return None
        if reason:
            self._reject(item, "too_large" if "capacity" in reason else "schema", reason, acks)
            return None
        if conflict:  # stored anyway: refusing it would let whoever sent first suppress the other
            self.suspect.count(
                "id_conflict",
                f"episode {ep.episode_id} of {ep.actor_id!r} arrived with another "
                "payload than the one stored (impersonation, or an actor reusing ids)",
                sender=item.actor,
            )
        seen.add((ep.key, digest))
        return Accepted(ep, item, digest)

    def _commit(self, accepted: list[Accepted], acks: list) -> None:
        state = self.state
        self._wait_insert_limiter(sum(a.episode.num_steps for a in accepted))
        with state.commit_lock:
            if state.wal:
                state.wal.append([a.item.raw for a in accepted])
            with state.store_lock:
                for a in accepted:
                    try:
                        state.store.insert(a.episode, a.digest)
                    except ValueError as exc:  # e.g. a schema clash inside this group, or capacity_bytes
                        self._reject(a.item, "too_large" if "capacity" in str(exc) else "schema", str(exc), acks)
                        continue
                    except Exception as exc:
                        self.errors.error(exc, f"insert of an episode from {a.item.actor}")
                        continue
                    state.limiter.inserts += a.episode.num_steps
                    self.bindings.stored(a.item.actor, a.item.zid)
                    acks.append(EpisodeAck(a.episode.actor_id, a.episode.episode_id, AckStatus.STORED, digest=a.digest))
        if state.wal and state.wal.bytes_since_rotate > self.config.wal_checkpoint_bytes:
            self._on_wal_growth()

    def _reject(self, item: Received, reason: str, detail: str, acks: list) -> None:
        """Count; tell the actor (REJECTED: do not resend) when the payload names the key's own actor."""
        self.state.info["last_rejection"] = f"{reason}: {detail}"[:200]
        self.rejected.count(reason, detail, sender=item.actor)
        try:
            fields = peek_fields(item.raw if item.raw is not None else item.head, self._peek_limits)
        except Exception:
            return
        actor, eid = fields.get("actor_id"), fields.get("episode_id")
        if actor == item.actor and isinstance(eid, int) and not isinstance(eid, bool) and 0 <= eid < 2**63:
            acks.append(EpisodeAck(actor, eid, AckStatus.REJECTED, detail[:500], item.payload_digest()))

    def _publish_ack(self, ack: EpisodeAck) -> None:
        try:
            key = keys.acks(self.run_id, keys.check_id(ack.actor_id, "actor"))  # never a wildcard
            self.session.put(key, encode(ack), congestion_control=zenoh.CongestionControl.BLOCK)
        except Exception as exc:  # the actor resends and gets DUPLICATE
            self.ack_errors.count(type(exc).__name__, f"ack to {ack.actor_id[:130]!r}: {exc}")

    def _wait_insert_limiter(self, n: int) -> None:
        state, cfg = self.state, self.config
        deadline = time.monotonic() + cfg.insert_wait_timeout_s
        while True:
            with state.store_lock:
                reason = state.limiter.insert_block_reason(n)
            if not reason:
                return
            if time.monotonic() >= deadline or self._stop.is_set():
                state.stats["insert_wait_timeouts"] += 1
                state.info["insert_wait"] = f"stored after waiting {cfg.insert_wait_timeout_s}s: {reason}"
                log.warning(
                    "insert waited %.1fs on the rate limiter and goes ahead: %s", cfg.insert_wait_timeout_s, reason
                )
                return
            time.sleep(0.005)
