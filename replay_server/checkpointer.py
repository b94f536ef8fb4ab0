"""Checkpointing the running replay: the restore at start (latest checkpoint + write-ahead
log), the periodic / WAL-size loop, and one consistent snapshot at a time. How a checkpoint
lies on disk is :mod:`replay_server.checkpoint_files`.

The snapshot is taken by reference under the locks (the only ingest pause, measured as
``checkpoint_max_pause_ms``) and written by this thread while ingest and sampling carry on.
WAL replay re-validates every record like ingest does (a record that fails is skipped and
counted), so a poisoned log cannot stop the server from starting.
"""
from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path
from typing import Optional

from protocol.codec import ProtocolError, payload_digest
from replay_server.checkpoint_files import CheckpointResult, list_checkpoints, load_latest, write_checkpoint
from replay_server.state import ReplayState
from replay_server.validation import decode_episode, decode_limits
from replay_server.wal import list_segments, read_segment, segment_path

log = logging.getLogger("replay_server")


class Checkpointer:
    def __init__(self, state: ReplayState, root: Path, run_id: str):
        self.state, self.config, self.run_id = state, state.config, run_id
        self.ckpt_root, self.wal_root = Path(root) / "checkpoints", Path(root) / "wal"
        self.errors = state.reasons("checkpoint_error", total="checkpoint_failures")
        state.stats.setdefault("checkpoints", 0)
        self.last: Optional[CheckpointResult] = None
        self.last_time = 0.0
        self.max_pause_s = 0.0
        self._lock = threading.Lock()  # one checkpoint at a time
        self._wanted = threading.Event()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self.restored_from = ""  #: the checkpoint restored at start, if any
        self.replayed = 0  #: acknowledged episodes replayed from the write-ahead log at start

    # ------------------------------------------------------------------ restore
    def restore(self) -> None:
        """Load the newest checkpoint, then replay the write-ahead log written after it."""
        state = self.state
        loaded = load_latest(self.ckpt_root)
        from_seq = 0
        if loaded:
            path, snap = loaded
            state.store.restore(snap)
            extra = snap.extra
            state.limiter.inserts = int(extra.get("limiter_inserts", 0))
            state.limiter.samples = int(extra.get("limiter_samples", 0))
            if "rng_state" in extra:
                state.rng.bit_generator.state = extra["rng_state"]
            state.stats.update({k: v for k, v in extra.get("stats", {}).items()})
            from_seq = int(extra.get("wal_segment", 0))
            self.restored_from = str(path)
            log.info("restored %s: %d episodes, %d transitions", path, state.store.num_episodes, state.store.size)
        replayed = skipped = 0
        if self.config.wal_enabled:
            limits = decode_limits(self.config)
            for seq in list_segments(self.wal_root):
                if seq < from_seq:
                    continue
                for raw in read_segment(segment_path(self.wal_root, seq)):
                    try:
                        replayed += self._replay_record(raw, limits)
                    except Exception as exc:  # e.g. a record today's limits refuse: skip it, keep starting
                        skipped += 1
                        log.warning("write-ahead-log record skipped: %s", exc)
        if replayed:
            log.info("replayed %d acknowledged episodes from the write-ahead log", replayed)
        self.replayed = replayed
        state.stats["wal_replayed_episodes"] = replayed
        state.stats["wal_skipped_records"] = skipped

    def restored(self) -> str:
        """Where the transitions held at start came from, in words for the start-up log."""
        parts = ([self.restored_from] if self.restored_from else []) + \
            ([f"{self.replayed} episodes of the write-ahead log"] if self.replayed else [])
        return " + ".join(parts) or "nothing (a fresh replay)"

    def _replay_record(self, raw: bytes, limits) -> int:
        store = self.state.store
        cfg = self.config
        if len(raw) > cfg.max_episode_bytes:
            raise ProtocolError("frame", f"{len(raw)} bytes exceeds max_episode_bytes={cfg.max_episode_bytes}")
        ep = decode_episode(raw, cfg, limits)
        digest = payload_digest(raw)
        if store.is_duplicate(ep.actor_id, ep.episode_id, digest):
            return 0
        reason = store.check(ep)
        if reason:
            raise ValueError(reason)
        store.insert(ep, digest)
        self.state.limiter.inserts += ep.num_steps
        return 1

    # ------------------------------------------------------------------ loop
    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="replay-checkpointer", daemon=True)
        self._thread.start()

    def want(self) -> None:
        """Ask for an early checkpoint (the WAL grew past ``wal_checkpoint_bytes``)."""
        self._wanted.set()

    def close(self, timeout: float = 60.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.error("checkpointer thread did not stop within %.0f s", timeout)

    def _loop(self) -> None:
        interval = self.config.checkpoint_interval_s
        next_at = time.monotonic() + interval if interval > 0 else float("inf")
        while not self._stop.is_set():
            timeout = min(1.0, max(0.0, next_at - time.monotonic()))
            wanted = self._wanted.wait(timeout)
            if self._stop.is_set():
                return
            if wanted or time.monotonic() >= next_at:
                self._wanted.clear()
                try:
                    self.checkpoint("wal size" if wanted else "periodic")
                except Exception as exc:
                    self.errors.error(exc, "checkpoint failed (the write-ahead log still holds every ack)")
                next_at = time.monotonic() + interval if interval > 0 else float("inf")

    # ------------------------------------------------------------------ one checkpoint
    def checkpoint(self, reason: str = "request") -> CheckpointResult:
        """Snapshot under the locks (the ingest pause), then write without holding them."""
        state = self.state
        with self._lock:
            t0 = time.perf_counter()
            with state.commit_lock:
                with state.store_lock:
                    snap = state.store.snapshot()
                    snap.extra = {
                        "limiter_inserts": state.limiter.inserts,
                        "limiter_samples": state.limiter.samples,
                        "rng_state": state.rng.bit_generator.state,
                        "stats": {k: v for k, v in state.stats.items() if isinstance(v, int)},
                        "run_id": self.run_id,
                        "reason": reason,
                    }
                seq = state.wal.rotate() if state.wal else 0
                snap.extra["wal_segment"] = seq
            pause = time.perf_counter() - t0
            self.max_pause_s = max(self.max_pause_s, pause)
            result = write_checkpoint(self.ckpt_root, snap, keep=self.config.checkpoint_keep)
            self.last, self.last_time = result, time.time()
            state.stats["checkpoints"] += 1
            if state.wal:
                kept = list_checkpoints(self.ckpt_root)
                oldest = json.loads((kept[0][1] / "manifest.json").read_text())["extra"].get("wal_segment", 0)
                state.wal.delete_before(int(oldest))
            log.info("checkpoint (%s) %s: %.1f MB in %.2fs, ingest paused %.1f ms", reason, result.path.name,
                     result.bytes / 1e6, result.seconds, pause * 1e3)
            return result
