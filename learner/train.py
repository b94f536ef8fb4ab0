"""The learner's loop: sample -> update -> priorities back -> weights out -> checkpoint.

Everything algorithmic lives in ``qattention``; this file only moves data between the
replay server (ZeroMQ), the agent and the fabric (Zenoh), and keeps the run resumable.

Nothing non-finite gets through: a batch with NaN/inf outside its point clouds is not
trained on (batch_guard.py), an update whose loss or gradients are non-finite is skipped
(``C2FARM.update``), and non-finite weights are neither published nor checkpointed. Each
is counted in ``health`` (status counters and the metrics CSV). Weights versions are never
reused, across restarts too (versions.py).
"""

from __future__ import annotations

import json
import logging
import random
import time
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np
import torch

from learner.acting_average import ActingAverage
from learner.batch_guard import label_out_of_range_rows, nonfinite_rows, nstep_out_of_range_rows
from learner.checkpoint import NonFiniteState, load_latest, save_checkpoint
from learner.config import LearnerConfig
from learner.metrics import MetricsLog
from learner.versions import PublishedVersion
from protocol import transition as tr
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext
from protocol.sample_wire import ReplayClient, ReplayError, ReplayTimeout
from protocol.weights_publisher import WeightsPublisher
from qattention.agent import C2FARM
from qattention.batch import TransitionBatch
from qattention.config import QAttentionConfig
from qattention.digest import network_digest

log = logging.getLogger("learner")


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


class Learner:
    """One learner process's state: agent, counters, RNGs; resumable from its checkpoints."""

    def __init__(self, config: LearnerConfig, qconfig: QAttentionConfig, ctx: RoleContext):
        self.config, self.qconfig, self.ctx = config, qconfig, ctx
        self.device = resolve_device(config.device)
        if self.device.type == "cpu":
            torch.set_num_threads(max(1, config.torch_threads))
        torch.manual_seed(ctx.seed)
        random.seed(ctx.seed)
        self.rng = np.random.default_rng(ctx.seed)
        self.agent = C2FARM(qconfig, device=self.device)
        self.step = 0  #: update() calls done
        self.checkpointed_at = time.monotonic()  #: when the last checkpoint was written (or the learner started)
        self.version = 0  #: last weights version published
        self.samples = 0  #: transitions consumed
        self.env_steps = 0  #: transitions the replay had received, as of the last batch (learning curves)
        self.checkpoint_dir = ctx.run_dir / "checkpoints" / "learner"
        self.published = PublishedVersion(ctx.run_dir / "learner" / "published_version")
        #: what was kept out of training: non-finite updates skipped, poisoned batches rejected,
        #: non-finite weight snapshots not published, non-finite states not checkpointed
        self.health = {"skipped_updates": 0, "rejected_batches": 0, "weights_refused": 0, "checkpoints_refused": 0}
        self._last_metrics: dict[str, float] = {}
        self._rates = {"updates_per_s": 0.0, "samples_per_s": 0.0}
        self.acting = ActingAverage(config.acting_average)  #: what actors act with (acting_average.py)
        self.restore()
        sent = self.published.read()
        if sent > self.version:
            log.info("weights versions up to %d were published after the checkpoint; continuing above them", sent)
            self.version = sent

    # -- persistence -----------------------------------------------------------------
    def state(self) -> dict:
        return {
            "agent": self.agent.state_dict(),
            "step": self.step,
            "version": self.version,
            "samples": self.samples,
            "env_steps": self.env_steps,
            "health": dict(self.health),
            "torch_rng": torch.get_rng_state(),
            "numpy_rng": json.dumps(self.rng.bit_generator.state),
            "python_rng": json.dumps(random.getstate()),
            "qattention_config": json.dumps(asdict(self.qconfig), default=str),
            "acting_average": self.acting.state_dict(),
        }

    def restore(self) -> bool:
        """Continue from the newest complete checkpoint, if there is one."""
        state = load_latest(self.checkpoint_dir, device="cpu")
        if state is None:
            return False
        self.agent.load_state_dict(state["agent"])
        self.step, self.version, self.samples = state["step"], state["version"], state["samples"]
        self.env_steps = state.get("env_steps", 0)
        self.health.update(state.get("health", {}))
        self.acting.load_state_dict(state.get("acting_average") or {})
        torch.set_rng_state(state["torch_rng"])
        self.rng.bit_generator.state = json.loads(state["numpy_rng"])
        python_state = json.loads(state["python_rng"])
        random.setstate((python_state[0], tuple(python_state[1]), python_state[2]))
        log.info("resumed from checkpoint at step %d, weights version %d", self.step, self.version)
        return True

    def checkpoint_due(self, now: float) -> bool:
        """Every ``checkpoint_every`` updates, and once ``checkpoint_every_s`` passed since the last one."""
        every_s = self.config.checkpoint_every_s
        return self.step % self.config.checkpoint_every == 0 or bool(every_s and now - self.checkpointed_at >= every_s)

    def checkpoint(self) -> bool:
        """Write a checkpoint; False (counted, previous ones kept) when the state is non-finite."""
        t0 = time.perf_counter()
        try:
            path = save_checkpoint(self.checkpoint_dir, self.step, self.state(), keep=self.config.checkpoint_keep)
        except NonFiniteState as exc:
            self.health["checkpoints_refused"] += 1
            log.error("%s; the previous checkpoint stays the latest", exc)
            return False
        log.info("checkpoint %s in %.2f s", path.name, time.perf_counter() - t0)
        self.checkpointed_at = time.monotonic()
        return True

    def publish(self, publisher: WeightsPublisher, announce: Callable[[], None] = lambda: None) -> bool:
        """Broadcast the current weights as the next version; False when refused (non-finite, counted).

        The order is the point: the version is recorded on disk first (a restart never reuses
        it), then ``announce``-d in the heartbeat (actors take only versions the learner has
        announced, protocol/weights_follower.py), then sent.
        """
        version = self.version + 1
        payload = publisher.encode(self.acting.weights(self.agent.weights()), version, self.step, self.env_steps)
        if payload is None:
            self.health["weights_refused"] += 1
            return False
        self.published.record(version)
        self.version = version
        announce()
        publisher.send(payload, version)
        return True

    # -- one update ------------------------------------------------------------------
    def train_step(self, arrays: dict[str, np.ndarray]) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
        """Train on one sampled batch; returns (metrics, rows, new priorities of those rows).

        A batch with a non-finite value outside its point clouds is not trained on: it is
        counted, and only its poisoned rows get a new priority, 0, so the replay rarely serves
        them again; the other rows keep theirs. ``metrics`` is then empty.
        """
        poisoned, bad = nonfinite_rows(arrays)
        reason = "non-finite values"
        if not poisoned:
            poisoned, bad = label_out_of_range_rows(arrays, self.qconfig.voxel_size, self.qconfig.depths,
                                                    self.qconfig.rotation_bins)
            reason = "act-time labels out of range"
        if not poisoned:
            poisoned, bad = nstep_out_of_range_rows(arrays)
            reason = "n-step fields out of range"
        if poisoned:
            self.health["rejected_batches"] += 1
            if _worth_logging(self.health["rejected_batches"]):
                log.warning("rejected batch %d: %s in %s (%d of %d rows)", self.health["rejected_batches"],
                            reason, ", ".join(poisoned), bad.sum(), len(bad))
            rows = np.flatnonzero(bad)
            return {}, rows, np.zeros(len(rows), np.float32)
        batch = TransitionBatch.from_arrays(arrays, self.qconfig.cameras, self.device)
        metrics, priorities = self.agent.update(batch)
        self.step += 1
        if self.acting.enabled and not metrics["skipped_nonfinite"]:
            self.acting.update(self.agent.weights())
        self.samples += int(arrays[tr.INDICES].shape[0])
        if metrics["skipped_nonfinite"]:
            self.health["skipped_updates"] += 1
            if _worth_logging(self.health["skipped_updates"]):
                log.warning("skipped update %d: non-finite loss or gradient (%d skipped so far)",
                            self.step, self.health["skipped_updates"])
        else:
            self._last_metrics = metrics
        return metrics, np.arange(len(priorities)), priorities

    def counters(self) -> dict[str, float]:
        return {
            "updates": self.step,
            "weights_version": self.version,
            "samples": self.samples,
            **self.health,
            **self._rates,
            **{k: v for k, v in self._last_metrics.items() if k.startswith(("loss/", "q_chosen/"))},
        }


@dataclass
class LearnerSetup:
    """What the learner role is told (``run(setup, ctx)``)."""

    learner: LearnerConfig  #: batch, optimiser, publishing, checkpoints and the replay endpoint to sample from
    network: QAttentionConfig  #: the Q-attention cascade to train (the actors act with the same one)


def run(setup: LearnerSetup, ctx: RoleContext) -> int:
    """Train until stopped (or ``max_updates``); checkpoint on the way out."""
    config, qconfig = setup.learner, setup.network
    learner = Learner(config, qconfig, ctx)
    session = open_session(ctx.fabric)
    heartbeat = Heartbeat(session, ctx.run_id, "learner", ctx.instance, counters=learner.counters,
                          info=lambda: {"device": str(learner.device)})
    publisher = WeightsPublisher(session, ctx.run_id, network_digest(qconfig))
    client = ReplayClient(config.replay_endpoint, config.batch_size, prefetch=config.prefetch,
                          curve_certificate=config.curve_certificate, curve_server_key=config.curve_server_key,
                          io_threads=config.zmq_io_threads)
    metrics_log = MetricsLog(ctx.run_dir / "metrics",
                             ctx.run_dir / "tensorboard" if config.tensorboard else None)
    # Actors may be waiting: publish what we have (fresh or resumed) before the first update.
    learner.publish(publisher, heartbeat.publish)
    window_start, window_updates, window_samples = time.monotonic(), 0, 0
    row_due = False  # a metrics row is written at the first applied update once due (never from a skipped one)
    try:
        while not ctx.stop.is_set():
            if config.max_updates and learner.step >= config.max_updates:
                break
            try:
                batch = client.sample(timeout_s=config.sample_timeout_s, stop=ctx.stop)
            except (ReplayTimeout, ReplayError) as exc:
                unreachable = client.handshake_failures or (client.curve and not client.handshakes)
                (log.warning if unreachable else log.info)("no batch yet (%s); asking again", exc)
                continue
            metrics, rows, priorities = learner.train_step(batch.arrays)
            if len(rows):
                client.update_priorities(batch.arrays[tr.INDICES][rows], batch.arrays[tr.KEYS][rows], priorities)
            if not metrics:
                continue  # a rejected batch: no update happened
            window_updates += 1
            window_samples += int(batch.arrays[tr.INDICES].shape[0])
            learner.env_steps = int(batch.info.get("transitions_inserted", learner.env_steps))
            if learner.step % config.publish_every == 0:
                learner.publish(publisher, heartbeat.publish)
            row_due = row_due or learner.step % config.log_every == 0
            if row_due and not metrics["skipped_nonfinite"]:
                # Only applied updates make rows: the CSV header is fixed by the first one (metrics.py).
                row_due = False
                elapsed = time.monotonic() - window_start
                learner._rates = {"updates_per_s": window_updates / elapsed, "samples_per_s": window_samples / elapsed}
                window_start, window_updates, window_samples = time.monotonic(), 0, 0
                applied = {k: v for k, v in metrics.items() if k != "skipped_nonfinite"}
                metrics_log.write(learner.step, {**applied, **learner._rates, "weights_version": learner.version,
                                                 **learner.health, **{f"replay_{k}": v for k, v in batch.info.items()}})
            if learner.checkpoint_due(time.monotonic()):
                learner.checkpoint()
    finally:
        heartbeat.state = "stopping"
        if learner.step:
            learner.checkpoint()
        metrics_log.close()
        client.close()
        publisher.close()
        heartbeat.close()
        session.close()
    return 0


def _worth_logging(count: int) -> bool:
    """Log the first few of a repeated warning, then every 100th, so a flood cannot drown the log."""
    return count <= 3 or count % 100 == 0
