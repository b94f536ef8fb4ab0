"""Configuration for the replay server (``c2farm replay``).

Composed into the root config by the CLI; every field has a default and a one-line doc.
Priorities arrive from the learner already raised to the PER exponent (the reference
applies alpha in the agent), so ``priority_alpha`` defaults to 1.0 and ``importance_beta``
to 0.5, which reproduces the reference's ``w = 1/sqrt(p)`` normalised by the batch max.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal, Optional

from protocol.config_checks import above, at_least, non_empty, one_of, within, zmq_endpoint
from protocol.zmq_curve import check_pair

#: zstd's compression levels (negative ones trade ratio for speed; 0 = zstd's default, 3).
ZSTD_LEVELS = (-(1 << 17), 22)


@dataclass
class ReplayConfig:
    """Settings of the replay server process."""

    # ZeroMQ endpoint the ROUTER sample service binds (the learner's DEALER connects to it): tcp://HOST:PORT, ipc:// or inproc://.
    zmq_endpoint: str = "tcp://127.0.0.1:5560"
    # Capacity in transitions, >= 1; the oldest episodes are evicted first beyond it.
    capacity_transitions: int = 100_000
    # Capacity in stored bytes (after compression); the oldest episodes are evicted first beyond it.
    capacity_bytes: int = 8 * 1024**3
    # Evict demo episodes only when no live-policy episode is left to evict.
    keep_demos: bool = True
    # Per-frame compression of image/point arrays in memory and in checkpoints.
    compression: Literal["none", "lz4", "zstd"] = "none"
    # zstd level (only used when compression == "zstd"), -131072..22.
    zstd_level: int = 1
    # Store float32 point clouds as float16 (RGB is always uint8 on the wire already).
    points_float16: bool = True
    # Exponent applied by the server to learner priorities, in [0, 1] (1.0: the learner already applied alpha).
    priority_alpha: float = 1.0
    # Importance-sampling exponent in [0, 1]: w = (N * P(i)) ** -beta / max over the batch (0.5 = reference).
    importance_beta: float = 0.5
    # Floor for updated priorities (> 0) so that no item becomes unsampleable by accident.
    priority_eps: float = 1e-6
    # Priority of the very first items, > 0 (new items get the running max of all priorities set).
    initial_priority: float = 1.0
    # Fraction of every batch drawn from demo transitions when the replay holds both demos and agent data; 0 = one
    # proportional table over everything (the reference).
    demo_fraction: float = 0.0
    # Serve n-step transitions: the next observation n decisions later (or at the episode's end) and the n rewards
    # between; 1 = one-step (the reference).
    n_step: int = 1
    # Minimum stored transitions before any batch is served, >= 1 (a run also wants it <= capacity_transitions).
    min_size_to_sample: int = 1_000
    # Target sampled transitions per inserted transition (Reverb SampleToInsertRatio), >= 0; 0 disables.
    samples_per_insert: float = 0.0
    # Allowed deviation (in sampled transitions) from the target ratio; with samples_per_insert > 0 it must be >= max(1,
    # samples_per_insert) and >= learner.batch_size.
    samples_per_insert_error_buffer: float = 10_000.0
    # Longest wait (s, > 0) of a sample request on the rate limiter before an error reply (also capped by the request).
    sample_wait_timeout_s: float = 10.0
    # Throttle inserts too when sampling falls behind the ratio (False: only sampling is throttled).
    limit_inserts: bool = False
    # Longest wait (s, > 0) of an insert on the rate limiter; after it the episode is stored anyway and counted.
    insert_wait_timeout_s: float = 5.0
    # ZeroMQ send high-water mark (messages = batches) of the ROUTER socket, >= 0 (0 = no limit).
    zmq_sndhwm: int = 8
    # ZeroMQ receive high-water mark (messages) of the ROUTER socket, >= 0 (0 = no limit).
    zmq_rcvhwm: int = 256
    # Largest accepted episode message in bytes; larger ones are rejected and counted.
    max_episode_bytes: int = 256 * 1024**2
    # Most episodes waiting between the Zenoh callback and the ingest thread.
    ingest_queue_size: int = 64
    # Most bytes waiting between the Zenoh callback and the ingest thread.
    ingest_queue_bytes: int = 512 * 1024**2
    # Longest wait (s, > 0) of the Zenoh callback on a full ingest queue; then the episode is dropped unacked (the actor
    # resends).
    ingest_put_timeout_s: float = 2.0
    # Most episodes committed together (one write-ahead-log fsync for all of them).
    ingest_batch_max: int = 32
    # Write every accepted episode to a write-ahead log before acking it (an ack then survives SIGKILL).
    wal_enabled: bool = True
    # fsync the write-ahead log before acking (survives power loss, not only process death).
    wal_fsync: bool = True
    # Write-ahead-log size (bytes) that triggers an early checkpoint.
    wal_checkpoint_bytes: int = 2 * 1024**3
    # Episode ids remembered per actor for duplicate detection (by id and payload digest; older ids are not judged).
    dedup_window: int = 10_000
    # Most actor ids whose dedup memory is kept (least recently stored forgotten first): bounds dedup memory.
    dedup_max_actors: int = 1024
    # Largest batch one sample request may ask for; larger ones get an error reply and are counted.
    max_batch_size: int = 512
    # Largest batch in bytes (estimated from the stored schema) one request may ask for; larger ones are refused.
    max_batch_bytes: int = 1 << 30
    # Most sample requests waiting on the rate limiter, in total; more get a retry-later error reply.
    max_pending_requests: int = 1024
    # Most sample requests waiting per client (ZeroMQ identity), so one client cannot take the whole queue.
    max_pending_per_client: int = 64
    # Largest sample-service message (request or priority update) in bytes; ZeroMQ disconnects a peer that sends more.
    max_request_bytes: int = 16 * 1024**2
    # CURVE on the sample service: this replay's certificate (NAME.key_secret of zmq.auth.create_certificates, chmod
    # 600); "" = plaintext (this and curve_clients both empty). Only allowed learners may sample or send priorities.
    curve_certificate: str = ""
    # CURVE: directory of the public NAME.key files of the learners allowed to connect (read at start); "" = plaintext.
    curve_clients: str = ""
    # ZeroMQ I/O threads of the sample service, >= 1 (CURVE encrypts in them; one connection uses one thread).
    zmq_io_threads: int = 1
    # Most steps (decisions) in one episode; longer episodes are rejected and counted.
    max_episode_steps: int = 1000
    # Most cameras in one episode; more are rejected and counted.
    max_episode_cameras: int = 8
    # Most episodes queued per sender (actor id of the key, or Zenoh source): beyond it its episodes are dropped unacked
    # at once, so a flood cannot starve others.
    ingest_sender_queue_size: int = 16
    # Most bytes queued per sender (see ingest_sender_queue_size).
    ingest_sender_queue_bytes: int = 256 * 1024**2
    # Seconds (> 0) an actor id stays bound to the Zenoh source (session id, when samples carry one) that last stored
    # under it; claims from another source meanwhile are impersonation. Released at once when the actor's liveliness
    # token goes (a restarted actor gets its id back); the TTL covers a lost DELETE.
    identity_bind_ttl_s: float = 15.0
    # Seconds between two log lines about the same rejection reason (the rest are only counted), >= 0.
    reject_log_interval_s: float = 5.0
    # Seconds between periodic checkpoints, >= 0; 0 disables periodic checkpoints.
    checkpoint_interval_s: float = 600.0
    # Number of complete checkpoints kept on disk.
    checkpoint_keep: int = 2
    # Write a checkpoint when the server stops (SIGTERM / ctx.stop): always without a write-ahead
    # log, else only while the store is at most stop_checkpoint_max_bytes (the WAL already holds
    # every stored episode, and a multi-GB write would outlast the launcher's stop grace).
    checkpoint_on_stop: bool = True
    # Largest store (bytes, >= 0) checkpointed on stop when the write-ahead log is on (~1 s here).
    stop_checkpoint_max_bytes: int = 256 * 2**20
    # Restore the latest complete checkpoint (and replay the write-ahead log) at start.
    restore_on_start: bool = True
    # Checkpoint/WAL directory override (a non-empty path); None means ctx.run_dir / "replay".
    checkpoint_dir: Optional[str] = None
    # Random seed for sampling, >= 0 (None: derived from the role context seed).
    seed: Optional[int] = None
    # Seconds between status messages (Heartbeat period), > 0.
    status_interval_s: float = 1.0

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ValueError for a setting no replay can run with (also after ``apply_overrides``)."""
        zmq_endpoint(self, "zmq_endpoint")
        one_of(self, "compression", ("none", "lz4", "zstd"))
        within(self, *ZSTD_LEVELS, "zstd_level")
        at_least(self, 1, "capacity_transitions", "capacity_bytes", "min_size_to_sample", "ingest_queue_size",
                 "ingest_queue_bytes", "ingest_batch_max", "wal_checkpoint_bytes", "checkpoint_keep",
                 "max_batch_size", "max_batch_bytes", "max_pending_requests", "max_pending_per_client",
                 "max_request_bytes", "max_episode_steps", "max_episode_cameras", "max_episode_bytes",
                 "ingest_sender_queue_size", "ingest_sender_queue_bytes", "dedup_window", "dedup_max_actors",
                 "zmq_io_threads")
        at_least(self, 0, "zmq_sndhwm", "zmq_rcvhwm", "stop_checkpoint_max_bytes", "seed", "samples_per_insert",
                 "samples_per_insert_error_buffer", "checkpoint_interval_s", "reject_log_interval_s")
        within(self, 0, 1, "priority_alpha", "importance_beta", "demo_fraction")
        above(self, 0, "priority_eps", "initial_priority", "sample_wait_timeout_s", "insert_wait_timeout_s",
              "ingest_put_timeout_s", "identity_bind_ttl_s", "status_interval_s")
        within(self, 1, 64, "n_step")
        non_empty(self, "checkpoint_dir")
        check_pair(self, "curve_certificate", "curve_clients", "directory")
        if self.samples_per_insert > 0 and self.samples_per_insert_error_buffer < max(1.0, self.samples_per_insert):
            raise ValueError(f"samples_per_insert_error_buffer must be >= max(1, samples_per_insert) = "
                             f"{max(1.0, self.samples_per_insert):g} when samples_per_insert > 0, or the rate "
                             f"limiter deadlocks (got {self.samples_per_insert_error_buffer})")


def apply_overrides(config: ReplayConfig, items: list[str]) -> ReplayConfig:
    """Apply ``name=value`` strings (``--set`` style) to ``config``, converting to each field's type."""
    types = {f.name: f.type for f in fields(config)}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip().removeprefix("replay.")
        if not sep or name not in types:
            raise ValueError(f"unknown replay setting {item!r}; known: {', '.join(types)}")
        kind = str(types[name])
        if text.lower() in ("none", "null") and "Optional" in kind:
            value = None
        elif kind.startswith("bool"):
            if text.lower() not in ("1", "0", "true", "false", "yes", "no"):
                raise ValueError(f"{name}: expected a boolean, got {text!r}")
            value = text.lower() in ("1", "true", "yes")
        elif kind.startswith("int") or kind == "Optional[int]":
            value = int(float(text)) if "e" in text.lower() else int(text)
        elif kind.startswith("float"):
            value = float(text)
        else:
            value = text
        setattr(config, name, value)
    config.validate()
    return config
