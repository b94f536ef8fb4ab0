"""The replay server process: Zenoh ingest, ZeroMQ sample service, checkpoints, status.

Threads (all daemon, all stoppable, every wait bounded):

- Zenoh callback: copies the payload into a bounded queue (episodes and bytes); if the queue
  stays full for ``ingest_put_timeout_s`` the episode is dropped *unacked* (the actor
  resends), so the callback never blocks Zenoh long enough to close the actor's transport.
- ingest: decodes and validates a group of episodes, rejects/dedups, appends the group to the
  write-ahead log (one fsync), inserts into the store, then acks each episode to its actor.
  An ack therefore means "durable": a SIGKILL loses nothing acknowledged.
- sampler: the ROUTER socket; sample requests wait (bounded) on the rate limiter, priority
  updates are applied with key checks.
- checkpointer: periodic (and early when the WAL grows past ``wal_checkpoint_bytes``); the
  store is snapshotted by reference under the locks (the only ingest pause, measured), and
  written by this thread while ingest and sampling carry on.
"""
from __future__ import annotations

import collections
import json
import logging
import threading
import time
from pathlib import Path
from typing import Optional

import numpy as np
import zenoh
import zmq

from protocol import keys
from protocol.codec import ProtocolError, peek_fields
from protocol.episode import Episode
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.messages import AckStatus, EpisodeAck, PriorityUpdate, SampleBatch, SampleRequest, decode, encode
from protocol.role import RoleContext
from replay_server.checkpoint import CheckpointResult, list_checkpoints, load_latest, write_checkpoint
from replay_server.config import ReplayConfig
from replay_server.ratelimiter import RateLimiter
from replay_server.storage import EpisodeStore
from replay_server.wire import batch_frames
from replay_server.wal import WriteAheadLog, list_segments, read_segment, segment_path

log = logging.getLogger("replay_server")


class _Oversize:
    def __init__(self, head: bytes, size: int):
        self.head, self.size = head, size


class IngestQueue:
    """A FIFO bounded both in items and in bytes; ``put`` waits at most ``timeout`` seconds."""

    def __init__(self, max_items: int, max_bytes: int):
        self._items: collections.deque = collections.deque()
        self._bytes = 0
        self.max_items, self.max_bytes = max(1, max_items), max(1, max_bytes)
        self._cond = threading.Condition()

    def __len__(self) -> int:
        return len(self._items)

    def put(self, item, nbytes: int, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._items and (len(self._items) >= self.max_items or self._bytes + nbytes > self.max_bytes):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            self._items.append((item, nbytes))
            self._bytes += nbytes
            self._cond.notify_all()
            return True

    def get_batch(self, max_items: int, timeout: float) -> list:
        with self._cond:
            if not self._items:
                self._cond.wait(timeout)
            out = []
            while self._items and len(out) < max_items:
                item, nbytes = self._items.popleft()
                self._bytes -= nbytes
                out.append(item)
            if out:
                self._cond.notify_all()
            return out


class ReplayService:
    """The replay server; ``start()`` then ``close()`` (``run()`` does both for a process)."""

    def __init__(self, config: ReplayConfig, ctx: RoleContext, session: zenoh.Session):
        self.config, self.ctx, self.session = config, ctx, session
        self.root = Path(config.checkpoint_dir) if config.checkpoint_dir else Path(ctx.run_dir) / "replay"
        self.ckpt_root = self.root / "checkpoints"
        self.wal_root = self.root / "wal"
        self.store = EpisodeStore(config)
        self.limiter = RateLimiter(
            config.samples_per_insert,
            config.min_size_to_sample,
            config.samples_per_insert_error_buffer,
            config.limit_inserts,
        )
        seed = config.seed if config.seed is not None else ctx.seed
        self.rng = np.random.default_rng(seed)
        self.store_lock = threading.Lock()  # guards store, limiter, rng
        self.commit_lock = threading.Lock()  # guards WAL + insert order against snapshots
        self._ckpt_lock = threading.Lock()  # one checkpoint at a time
        self.queue = IngestQueue(config.ingest_queue_size, config.ingest_queue_bytes)
        self.wal: Optional[WriteAheadLog] = None
        self.stats = collections.Counter()
        self.info: dict[str, str] = {}
        self.last_checkpoint: Optional[CheckpointResult] = None
        self.last_checkpoint_time = 0.0
        self.max_pause_s = 0.0
        self.restored_from = ""
        self._stop_ingest = threading.Event()
        self._stop_sampler = threading.Event()
        self._stop_ckpt = threading.Event()
        self._ckpt_wanted = threading.Event()
        self._threads: list[threading.Thread] = []
        self._subscriber = None
        self._heartbeat: Optional[Heartbeat] = None
        self._zctx: Optional[zmq.Context] = None
        self._router: Optional[zmq.Socket] = None
        self._rate_last = (time.monotonic(), 0, 0)
        self._started = False

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        if self.config.restore_on_start:
            self._restore()
        self.stats["restore_seconds"] = time.perf_counter() - t0
        if self.config.wal_enabled:
            self.wal = WriteAheadLog(self.wal_root, fsync=self.config.wal_fsync)
        self._zctx = zmq.Context()
        self._router = self._zctx.socket(zmq.ROUTER)
        self._router.setsockopt(zmq.LINGER, 0)
        self._router.setsockopt(zmq.SNDHWM, self.config.zmq_sndhwm)
        self._router.setsockopt(zmq.RCVHWM, self.config.zmq_rcvhwm)
        self._router.setsockopt(zmq.ROUTER_MANDATORY, 1)
        self._router.setsockopt(zmq.MAXMSGSIZE, 16 * 1024 * 1024)  # requests and updates are small
        self._router.bind(self.config.zmq_endpoint)
        self.zmq_endpoint = self._router.getsockopt_string(zmq.LAST_ENDPOINT)
        for name, target in (("ingest", self._ingest_loop), ("sampler", self._sample_loop), ("checkpointer", self._checkpoint_loop)):
            t = threading.Thread(target=target, name=f"replay-{name}", daemon=True)
            t.start()
            self._threads.append(t)
        self._subscriber = self.session.declare_subscriber(keys.episodes(self.ctx.run_id, "*"), self._on_episode)
        self._heartbeat = Heartbeat(
            self.session, self.ctx.run_id, "replay", self.ctx.instance,
            counters=self.counters, info=self.status_info, period_s=self.config.status_interval_s,
        )
        self._started = True
        log.info(
            "replay %s serving: episodes on %s, samples on %s, %d transitions restored from %s",
            self.ctx.instance, keys.episodes(self.ctx.run_id, "*"), self.zmq_endpoint, self.store.size,
            self.restored_from or "nothing",
        )

    def close(self) -> None:
        """Stop ingest (draining what is queued), sampling, then checkpoint (if configured)."""
        if not self._started:
            return
        self._started = False
        if self._heartbeat:
            self._heartbeat.state = "stopping"
        if self._subscriber is not None:
            self._subscriber.undeclare()
        self._stop_ingest.set()
        self._stop_sampler.set()
        self._stop_ckpt.set()
        for t in self._threads:
            t.join(timeout=60)
            if t.is_alive():
                log.error("thread %s did not stop within 60 s", t.name)
        if self.config.checkpoint_on_stop:
            try:
                self.checkpoint("stop")
            except Exception:
                log.exception("checkpoint on stop failed")
        if self.wal:
            self.wal.close()
        if self._router is not None:
            self._router.close(linger=0)
        if self._zctx is not None:
            self._zctx.term()
        if self._heartbeat:
            self._heartbeat.close("stopped")

    # ------------------------------------------------------------------ restore
    def _restore(self) -> None:
        loaded = load_latest(self.ckpt_root)
        from_seq = 0
        if loaded:
            path, snap = loaded
            self.store.restore(snap)
            extra = snap.extra
            self.limiter.inserts = int(extra.get("limiter_inserts", 0))
            self.limiter.samples = int(extra.get("limiter_samples", 0))
            if "rng_state" in extra:
                self.rng.bit_generator.state = extra["rng_state"]
            self.stats.update({k: v for k, v in extra.get("stats", {}).items()})
            from_seq = int(extra.get("wal_segment", 0))
            self.restored_from = str(path)
            log.info("restored %s: %d episodes, %d transitions", path, self.store.num_episodes, self.store.size)
        replayed = 0
        if self.config.wal_enabled:
            for seq in list_segments(self.wal_root):
                if seq < from_seq:
                    continue
                for raw in read_segment(segment_path(self.wal_root, seq)):
                    try:
                        ep = decode(raw, expect=Episode, max_bytes=max(self.config.max_episode_bytes, len(raw)))
                    except ProtocolError:
                        continue
                    if self.store.is_duplicate(*ep.key) or self.store.check(ep):
                        continue
                    try:
                        self.store.insert(ep)
                    except ValueError:
                        continue
                    self.limiter.inserts += ep.num_steps
                    replayed += 1
        if replayed:
            log.info("replayed %d acknowledged episodes from the write-ahead log", replayed)
        self.stats["wal_replayed_episodes"] = replayed

    # ------------------------------------------------------------------ ingest
    def _on_episode(self, sample) -> None:
        try:
            n = len(sample.payload)
            if n > self.config.max_episode_bytes:
                item, size = _Oversize(sample.payload.to_bytes()[: 1 << 20], n), 1 << 20
            else:
                item, size = sample.payload.to_bytes(), n
            if not self.queue.put(item, size, self.config.ingest_put_timeout_s):
                self.stats["dropped_backpressure"] += 1
                log.warning("ingest queue full for %.1fs: episode dropped unacked (the actor will resend)",
                            self.config.ingest_put_timeout_s)
        except Exception:  # never raise into zenoh
            log.exception("episode callback failed")

    def _ingest_loop(self) -> None:
        while True:
            items = self.queue.get_batch(self.config.ingest_batch_max, timeout=0.1)
            if not items:
                if self._stop_ingest.is_set():
                    return
                continue
            try:
                self._ingest(items)
            except Exception:
                log.exception("ingest of %d episodes failed (they are not acked; actors will resend)", len(items))
                self.stats["ingest_errors"] += 1

    def _reject(self, data: bytes, reason: str, acks: list) -> None:
        self.stats["rejected"] += 1
        self.info["last_rejection"] = reason[:200]
        identity = None
        try:
            fields = peek_fields(data)
            actor, eid = fields.get("actor_id"), fields.get("episode_id")
            if isinstance(actor, str) and isinstance(eid, int) and not isinstance(eid, bool) and eid >= 0:
                keys.check_id(actor, "actor")
                identity = (actor, eid)
        except Exception:
            pass
        log.warning("rejected an episode message from %s: %s", identity or "an unknown sender", reason)
        if identity:
            acks.append(EpisodeAck(identity[0], identity[1], AckStatus.REJECTED, reason[:500]))

    def _ingest(self, items: list) -> None:
        acks: list[EpisodeAck] = []
        accepted: list[tuple[Episode, bytes]] = []
        batch_keys: set = set()
        for item in items:
            if isinstance(item, _Oversize):
                self._reject(item.head, f"message of {item.size} bytes exceeds max_episode_bytes={self.config.max_episode_bytes}", acks)
                continue
            try:
                ep = decode(item, expect=Episode, max_bytes=self.config.max_episode_bytes)
            except ProtocolError as exc:
                self._reject(item, str(exc), acks)
                continue
            with self.store_lock:
                dup = self.store.is_duplicate(*ep.key)
                reason = "" if dup else self.store.check(ep)
            if dup or ep.key in batch_keys:
                self.stats["duplicates"] += 1
                acks.append(EpisodeAck(ep.actor_id, ep.episode_id, AckStatus.DUPLICATE))
                continue
            if reason:
                self._reject(item, reason, acks)
                continue
            batch_keys.add(ep.key)
            accepted.append((ep, item))
        if accepted:
            self._wait_insert_limiter(sum(ep.num_steps for ep, _ in accepted))
            with self.commit_lock:
                if self.wal:
                    self.wal.append([raw for _, raw in accepted])
                with self.store_lock:
                    for ep, raw in accepted:
                        try:
                            self.store.insert(ep)
                        except ValueError as exc:  # e.g. a schema clash inside this group
                            self._reject(raw, str(exc), acks)
                            continue
                        self.limiter.inserts += ep.num_steps
                        acks.append(EpisodeAck(ep.actor_id, ep.episode_id, AckStatus.STORED))
            if self.wal and self.wal.bytes_since_rotate > self.config.wal_checkpoint_bytes:
                self._ckpt_wanted.set()
        for ack in acks:
            try:
                self.session.put(
                    keys.acks(self.ctx.run_id, ack.actor_id), encode(ack),
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
            except Exception:
                log.exception("ack to %s failed (it will resend and get DUPLICATE)", ack.actor_id)

    def _wait_insert_limiter(self, n: int) -> None:
        deadline = time.monotonic() + self.config.insert_wait_timeout_s
        while True:
            with self.store_lock:
                reason = self.limiter.insert_block_reason(n)
            if not reason:
                return
            if time.monotonic() >= deadline or self._stop_ingest.is_set():
                self.stats["insert_wait_timeouts"] += 1
                self.info["insert_wait"] = f"stored after waiting {self.config.insert_wait_timeout_s}s: {reason}"
                log.warning("insert waited %.1fs on the rate limiter and goes ahead: %s",
                            self.config.insert_wait_timeout_s, reason)
                return
            time.sleep(0.005)

    # ------------------------------------------------------------------ sampling
    def _sample_loop(self) -> None:
        sock = self._router
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        pending: collections.deque = collections.deque()
        while not self._stop_sampler.is_set():
            try:
                if poller.poll(5 if pending else 100):
                    for _ in range(1024):
                        try:
                            frames = sock.recv_multipart(zmq.NOBLOCK, copy=False)
                        except zmq.Again:
                            break
                        self._handle_request(frames, pending)
                self._serve_pending(pending)
            except Exception:
                log.exception("sample service error")
                self.stats["sample_errors"] += 1
                time.sleep(0.01)

    def _handle_request(self, frames, pending) -> None:
        if len(frames) != 2:
            self.stats["zmq_rejected"] += 1
            return
        ident, frame = frames[0].bytes, frames[1]
        try:
            msg = decode(frame.buffer, max_bytes=16 * 1024 * 1024)
        except ProtocolError as exc:
            self.stats["zmq_rejected"] += 1
            self.info["last_zmq_rejection"] = str(exc)[:200]
            log.warning("rejected a sample-service message: %s", exc)
            return
        if isinstance(msg, SampleRequest):
            wait = min(msg.timeout_ms / 1000.0, self.config.sample_wait_timeout_s)
            if len(pending) >= 1024:  # bounded: a client that floods requests gets errors, not memory
                self.stats["sample_timeouts"] += 1
                self._send(ident, SampleBatch(msg.request_id, {}, "rate limiter: too many requests waiting", {}))
                return
            pending.append((ident, msg, time.monotonic() + wait, wait))
        elif isinstance(msg, PriorityUpdate):
            with self.store_lock:
                self.store.update_priorities(msg.indices, msg.keys, msg.priorities)
        else:
            self.stats["zmq_rejected"] += 1
            log.warning("unexpected %s on the sample service", type(msg).__name__)

    def _serve_pending(self, pending) -> None:
        now = time.monotonic()
        keep = collections.deque()
        blocked = False
        while pending:
            ident, req, deadline, wait = pending.popleft()
            refs = None
            if not blocked:
                with self.store_lock:
                    reason = self.limiter.sample_block_reason(req.batch_size, self.store.size)
                    if not reason:
                        refs = self.store.sample(req.batch_size, self.rng, self.config.importance_beta,
                                                 self.config.demo_fraction)
                        self.limiter.samples += req.batch_size
                        info = self._batch_info(refs[4])
                if reason:
                    self.info["sample_wait"] = reason
                    blocked = True  # serve in order
            else:
                with self.store_lock:
                    reason = self.limiter.sample_block_reason(req.batch_size, self.store.size)
            if refs is not None:
                slots, item_keys, probs, weights, episodes, ts = refs
                arrays = self.store.gather(episodes, ts)
                arrays.update(indices=slots, keys=item_keys, weights=weights, probabilities=probs)
                self._send(ident, SampleBatch(req.request_id, arrays, "", info))
                self.stats["batches_served"] += 1
            elif now >= deadline:
                self.stats["sample_timeouts"] += 1
                self._send(ident, SampleBatch(req.request_id, {}, f"rate limiter: no batch within {wait:.1f}s: {reason}", {}))
            else:
                keep.append((ident, req, deadline, wait))
        pending.extend(keep)

    def _batch_info(self, episodes: list) -> dict[str, float]:
        """Scalars sent with a batch (the learner logs each as ``replay_<key>``)."""
        return {
            "replay_size": float(self.store.size),
            "samples_per_insert": self.limiter.achieved(),
            "transitions_inserted": float(self.limiter.inserts),
            "demo_share": sum(ep.is_demo for ep in episodes) / max(1, len(episodes)),  # of this batch
        }

    def _send(self, ident: bytes, batch: SampleBatch) -> None:
        try:
            self._router.send_multipart([ident] + batch_frames(batch), flags=zmq.NOBLOCK, copy=False)
        except (zmq.Again, zmq.ZMQError) as exc:  # learner gone or not reading: drop, it re-requests
            self.stats["dropped_replies"] += 1
            (log.warning if isinstance(exc, zmq.Again) else log.info)("batch reply dropped (%s)", exc)

    # ------------------------------------------------------------------ checkpoints
    def _checkpoint_loop(self) -> None:
        interval = self.config.checkpoint_interval_s
        next_at = time.monotonic() + interval if interval > 0 else float("inf")
        while not self._stop_ckpt.is_set():
            timeout = min(1.0, max(0.0, next_at - time.monotonic()))
            wanted = self._ckpt_wanted.wait(timeout)
            if self._stop_ckpt.is_set():
                return
            if wanted or time.monotonic() >= next_at:
                self._ckpt_wanted.clear()
                try:
                    self.checkpoint("wal size" if wanted else "periodic")
                except Exception:
                    log.exception("checkpoint failed (the write-ahead log still holds every ack)")
                    self.stats["checkpoint_failures"] += 1
                next_at = time.monotonic() + interval if interval > 0 else float("inf")

    def checkpoint(self, reason: str = "request") -> CheckpointResult:
        """Snapshot under the locks (the ingest pause), then write without holding them."""
        with self._ckpt_lock:
            t0 = time.perf_counter()
            with self.commit_lock:
                with self.store_lock:
                    snap = self.store.snapshot()
                    snap.extra = {
                        "limiter_inserts": self.limiter.inserts,
                        "limiter_samples": self.limiter.samples,
                        "rng_state": self.rng.bit_generator.state,
                        "stats": {k: v for k, v in self.stats.items() if isinstance(v, int)},
                        "run_id": self.ctx.run_id,
                        "reason": reason,
                    }
                seq = self.wal.rotate() if self.wal else 0
                snap.extra["wal_segment"] = seq
            pause = time.perf_counter() - t0
            self.max_pause_s = max(self.max_pause_s, pause)
            result = write_checkpoint(self.ckpt_root, snap, keep=self.config.checkpoint_keep)
            self.last_checkpoint, self.last_checkpoint_time = result, time.time()
            self.stats["checkpoints"] += 1
            if self.wal:
                kept = list_checkpoints(self.ckpt_root)
                oldest = json.loads((kept[0][1] / "manifest.json").read_text())["extra"].get("wal_segment", 0)
                self.wal.delete_before(int(oldest))
            log.info("checkpoint (%s) %s: %.1f MB in %.2fs, ingest paused %.1f ms", reason, result.path.name,
                     result.bytes / 1e6, result.seconds, pause * 1e3)
            return result

    # ------------------------------------------------------------------ status
    def counters(self) -> dict[str, float]:
        now = time.monotonic()
        with self.store_lock:
            size, eps, nbytes = self.store.size, self.store.num_episodes, self.store.bytes
            demo_size = self.store.demo_size
            ins, smp = self.limiter.inserts, self.limiter.samples
            sc = dict(self.store.counters)
            achieved = self.limiter.achieved()
        t_last, ins_last, smp_last = self._rate_last
        dt = max(1e-6, now - t_last)
        self._rate_last = (now, ins, smp)
        out = {
            "size_transitions": size,
            "size_episodes": eps,
            "demo_transitions": demo_size,
            "agent_transitions": size - demo_size,
            "bytes": nbytes,
            "capacity_transitions": self.store.capacity,
            "capacity_bytes": self.config.capacity_bytes,
            "inserts_per_s": (ins - ins_last) / dt,
            "samples_per_s": (smp - smp_last) / dt,
            "samples_per_insert": achieved,
            "samples_per_insert_target": self.limiter.spi,
            "transitions_inserted": ins,
            "transitions_sampled": smp,
            "demo_transitions_sampled": sc["demo_transitions_sampled"],
            "episodes_stored": sc["episodes_stored"],
            "episodes_evicted": sc["episodes_evicted"],
            "priority_updates": sc["priority_updates"],
            "stale_priority_updates": sc["stale_priority_updates"],
            "ingest_queue": len(self.queue),
            "last_checkpoint_time": self.last_checkpoint_time,
            "last_checkpoint_seconds": self.last_checkpoint.seconds if self.last_checkpoint else 0.0,
            "last_checkpoint_bytes": self.last_checkpoint.bytes if self.last_checkpoint else 0,
            "checkpoint_max_pause_ms": self.max_pause_s * 1e3,
        }
        for name in ("rejected", "duplicates", "dropped_backpressure", "sample_timeouts", "batches_served",
                     "zmq_rejected", "dropped_replies", "insert_wait_timeouts", "checkpoints",
                     "checkpoint_failures", "ingest_errors", "wal_replayed_episodes"):
            out[name] = self.stats.get(name, 0)
        return {k: float(v) for k, v in out.items()}

    def status_info(self) -> dict[str, str]:
        info = dict(self.info)
        info["zmq_endpoint"] = getattr(self, "zmq_endpoint", "")
        info["last_checkpoint"] = str(self.last_checkpoint.path) if self.last_checkpoint else ""
        info["restored_from"] = self.restored_from
        return info


def run(config: ReplayConfig, ctx: RoleContext) -> int:
    """Role entry point: serve until ``ctx.stop`` is set, checkpoint, return 0."""
    session = open_session(ctx.fabric)
    service = ReplayService(config, ctx, session)
    try:
        service.start()
        while not ctx.stop.wait(0.2):
            pass
    finally:
        service.close()
        session.close()
    return 0
