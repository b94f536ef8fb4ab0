"""The replay server process: composes ingest, sampling and checkpointing, and owns status.

- :mod:`replay_server.ingest`: Zenoh episodes -> validated one by one -> WAL -> store -> acks;
- :mod:`replay_server.sample_service`: the ZeroMQ ROUTER serving batches and priority updates;
- :mod:`replay_server.checkpointer`: restore at start, periodic / WAL-size checkpoints.

They share one :class:`ReplayState` (store, rate limiter, RNG, WAL, counters, locks). Every
thread is a daemon, stoppable, and every wait is bounded. Status counters carry everything
counted, including each rejection by reason (``ingest_rejected_<reason>``,
``ingest_dropped_<reason>``, ``zmq_rejected_<reason>``, ``<where>_error_<exception type>``).
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Optional

import zenoh

from protocol import keys
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext
from replay_server.checkpoint_files import CheckpointResult
from replay_server.checkpointer import Checkpointer
from replay_server.config import ReplayConfig
from replay_server.ingest import Ingest
from replay_server.sample_service import SampleService
from replay_server.state import ReplayState
from replay_server.wal import WriteAheadLog

log = logging.getLogger("replay_server")


class ReplayService:
    """The replay server; ``start()`` then ``close()`` (``run()`` does both for a process)."""

    def __init__(self, config: ReplayConfig, ctx: RoleContext, session: zenoh.Session):
        self.config, self.ctx, self.session = config, ctx, session
        self.root = Path(config.checkpoint_dir) if config.checkpoint_dir else Path(ctx.run_dir) / "replay"
        self.state = ReplayState.create(config, config.seed if config.seed is not None else ctx.seed)
        self.checkpointer = Checkpointer(self.state, self.root, ctx.run_id)
        self.ingest = Ingest(self.state, session, ctx.run_id, on_wal_growth=self.checkpointer.want)
        self.sampler = SampleService(self.state)
        self._heartbeat: Optional[Heartbeat] = None
        self._rate_last = (time.monotonic(), 0, 0)
        self._started = False

    # shared state, as attributes (benchmarks and tests read them)
    store = property(lambda self: self.state.store)
    limiter = property(lambda self: self.state.limiter)
    stats = property(lambda self: self.state.stats)
    info = property(lambda self: self.state.info)
    queue = property(lambda self: self.ingest.queue)
    zmq_endpoint = property(lambda self: self.sampler.endpoint)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        if self.config.restore_on_start:
            self.checkpointer.restore()
        self.state.stats["restore_seconds"] = time.perf_counter() - t0
        if self.config.wal_enabled:
            self.state.wal = WriteAheadLog(self.checkpointer.wal_root, fsync=self.config.wal_fsync)
        self.sampler.start()
        self.checkpointer.start()
        self.ingest.start()
        self._heartbeat = Heartbeat(
            self.session, self.ctx.run_id, "replay", self.ctx.instance,
            counters=self.counters, info=self.status_info, period_s=self.config.status_interval_s,
        )
        self._started = True
        log.info(
            "replay %s serving: episodes on %s, samples on %s, %d transitions restored from %s",
            self.ctx.instance, keys.episodes(self.ctx.run_id, "*"), self.zmq_endpoint, self.store.size,
            self.checkpointer.restored(),
        )

    def close(self) -> None:
        """Stop ingest (draining what is queued), sampling, then checkpoint (if configured)."""
        if not self._started:
            return
        self._started = False
        if self._heartbeat:
            self._heartbeat.state = "stopping"
        self.ingest.stop_receiving()
        self.ingest.close()
        self.sampler.close()
        self.checkpointer.close()
        if self._checkpoint_on_stop():
            try:
                self.checkpoint("stop")
            except Exception:
                log.exception("checkpoint on stop failed")
        if self.state.wal:
            self.state.wal.close()
        if self._heartbeat:
            self._heartbeat.close("stopped")

    def checkpoint(self, reason: str = "request") -> CheckpointResult:
        return self.checkpointer.checkpoint(reason)

    def _checkpoint_on_stop(self) -> bool:
        cfg = self.config
        if not cfg.checkpoint_on_stop:
            return False
        if self.state.wal is None or self.state.store.bytes <= cfg.stop_checkpoint_max_bytes:
            return True
        log.info("no checkpoint on stop: %.0f MB stored, the write-ahead log holds them (next start replays it)",
                 self.state.store.bytes / 2**20)
        return False

    # ------------------------------------------------------------------ status
    def counters(self) -> dict[str, float]:
        now = time.monotonic()
        state = self.state
        with state.store_lock:
            store, limiter = state.store, state.limiter
            size, eps, nbytes = store.size, store.num_episodes, store.bytes
            demo_size = store.demo_size
            ins, smp = limiter.inserts, limiter.samples
            sc = dict(store.counters)
            achieved = limiter.achieved()
            dedup_actors = len(store.dedup.by_actor)
        t_last, ins_last, smp_last = self._rate_last
        dt = max(1e-6, now - t_last)
        self._rate_last = (now, ins, smp)
        ck = self.checkpointer
        out = {k: v for k, v in state.stats.items() if isinstance(v, (int, float))}  # every counter, by reason too
        out.update({
            "size_transitions": size,
            "size_episodes": eps,
            "demo_transitions": demo_size,
            "agent_transitions": size - demo_size,
            "bytes": nbytes,
            "capacity_transitions": store.capacity,
            "capacity_bytes": self.config.capacity_bytes,
            "inserts_per_s": (ins - ins_last) / dt,
            "samples_per_s": (smp - smp_last) / dt,
            "samples_per_insert": achieved,
            "samples_per_insert_target": limiter.spi,
            "transitions_inserted": ins,
            "transitions_sampled": smp,
            "demo_transitions_sampled": sc["demo_transitions_sampled"],
            "episodes_stored": sc["episodes_stored"],
            "episodes_evicted": sc["episodes_evicted"],
            "priority_updates": sc["priority_updates"],
            "stale_priority_updates": sc["stale_priority_updates"],
            "ingest_queue": len(self.ingest.queue),
            "ingest_queue_bytes": self.ingest.queue.nbytes,
            "ingest_queue_peak": self.ingest.queue.peak_items,
            "ingest_queue_peak_bytes": self.ingest.queue.peak_bytes,
            "ingest_senders": self.ingest.queue.senders,
            "identity_bindings": len(self.ingest.bindings),
            "dedup_actors": dedup_actors,
            "sample_requests_pending": self.sampler.pending,
            "last_checkpoint_time": ck.last_time,
            "last_checkpoint_seconds": ck.last.seconds if ck.last else 0.0,
            "last_checkpoint_bytes": ck.last.bytes if ck.last else 0,
            "checkpoint_max_pause_ms": ck.max_pause_s * 1e3,
        })
        return {k: float(v) for k, v in out.items()}

    def status_info(self) -> dict[str, str]:
        info = dict(self.state.info)
        info["zmq_endpoint"] = self.zmq_endpoint
        info["last_checkpoint"] = str(self.checkpointer.last.path) if self.checkpointer.last else ""
        info["restored_from"] = self.checkpointer.restored_from
        for name, counter in (("last_rejection", self.ingest.rejected), ("last_zmq_rejection", self.sampler.rejected)):
            if counter.last:
                info[name] = counter.last
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
