"""The learner's loop: sample -> update -> priorities back -> weights out -> checkpoint.

Everything algorithmic lives in ``qattention``; this file only moves data between the
replay server (ZeroMQ), the agent and the fabric (Zenoh), and keeps the run resumable.
"""

from __future__ import annotations

import json
import logging
import random
import time
from dataclasses import asdict

import numpy as np
import torch

from learner.checkpoint import load_latest, save_checkpoint
from learner.config import LearnerConfig
from learner.metrics import MetricsLog
from learner.weights import WeightsPublisher
from protocol.episode import EXTRA_PREFIX
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext
from qattention.agent import C2FARM
from qattention.batch import TransitionBatch
from qattention.config import QAttentionConfig
from qattention.digest import network_digest
from replay_server.client import ReplayClient, ReplayError, ReplayTimeout

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
        self.version = 0  #: last weights version published
        self.samples = 0  #: transitions consumed
        self.env_steps = 0  #: transitions the replay had received, as of the last batch (learning curves)
        self.checkpoint_dir = ctx.run_dir / "checkpoints" / "learner"
        self._last_metrics: dict[str, float] = {}
        self._rates = {"updates_per_s": 0.0, "samples_per_s": 0.0}
        self.restore()

    # -- persistence -----------------------------------------------------------------
    def state(self) -> dict:
        return {
            "agent": self.agent.state_dict(),
            "step": self.step,
            "version": self.version,
            "samples": self.samples,
            "env_steps": self.env_steps,
            "torch_rng": torch.get_rng_state(),
            "numpy_rng": json.dumps(self.rng.bit_generator.state),
            "python_rng": json.dumps(random.getstate()),
            "qattention_config": json.dumps(asdict(self.qconfig), default=str),
        }

    def restore(self) -> bool:
        """Continue from the newest complete checkpoint, if there is one."""
        state = load_latest(self.checkpoint_dir, device="cpu")
        if state is None:
            return False
        self.agent.load_state_dict(state["agent"])
        self.step, self.version, self.samples = state["step"], state["version"], state["samples"]
        self.env_steps = state.get("env_steps", 0)
        torch.set_rng_state(state["torch_rng"])
        self.rng.bit_generator.state = json.loads(state["numpy_rng"])
        python_state = json.loads(state["python_rng"])
        random.setstate((python_state[0], tuple(python_state[1]), python_state[2]))
        log.info("resumed from checkpoint at step %d, weights version %d", self.step, self.version)
        return True

    def checkpoint(self) -> None:
        t0 = time.perf_counter()
        path = save_checkpoint(self.checkpoint_dir, self.step, self.state(), keep=self.config.checkpoint_keep)
        log.info("checkpoint %s in %.2f s", path.name, time.perf_counter() - t0)

    # -- one update ------------------------------------------------------------------
    def train_step(self, arrays: dict[str, np.ndarray]) -> tuple[dict[str, float], np.ndarray]:
        # Act-time labels travel as observation extras ("extra_voxel_indices", ...).
        arrays = {name.removeprefix(EXTRA_PREFIX): a for name, a in arrays.items()}
        batch = TransitionBatch.from_arrays(arrays, self.qconfig.cameras, self.device)
        metrics, priorities = self.agent.update(batch)
        self.step += 1
        self.samples += int(arrays["indices"].shape[0])
        return metrics, priorities

    def counters(self) -> dict[str, float]:
        return {
            "updates": self.step,
            "weights_version": self.version,
            "samples": self.samples,
            **self._rates,
            **{k: v for k, v in self._last_metrics.items() if k.startswith(("loss/", "q_chosen/"))},
        }


def run(config: LearnerConfig, qconfig: QAttentionConfig, ctx: RoleContext) -> int:
    """Train until stopped (or ``max_updates``); checkpoint on the way out."""
    learner = Learner(config, qconfig, ctx)
    session = open_session(ctx.fabric)
    heartbeat = Heartbeat(session, ctx.run_id, "learner", ctx.instance, counters=learner.counters,
                          info=lambda: {"device": str(learner.device)})
    publisher = WeightsPublisher(session, ctx.run_id, network_digest(qconfig))
    client = ReplayClient(config.replay_endpoint, config.batch_size, prefetch=config.prefetch)
    metrics_log = MetricsLog(ctx.run_dir / "metrics",
                             ctx.run_dir / "tensorboard" if config.tensorboard else None)
    # Actors may be waiting: publish what we have (fresh or resumed) before the first update.
    learner.version += 1
    publisher.publish(learner.agent.weights(), learner.version, learner.step, learner.env_steps)
    window_start, window_updates, window_samples = time.monotonic(), 0, 0
    try:
        while not ctx.stop.is_set():
            if config.max_updates and learner.step >= config.max_updates:
                break
            try:
                batch = client.sample(timeout_s=config.sample_timeout_s)
            except (ReplayTimeout, ReplayError) as exc:
                log.info("no batch yet (%s); asking again", exc)
                continue
            metrics, priorities = learner.train_step(batch.arrays)
            client.update_priorities(batch.arrays["indices"], batch.arrays["keys"], priorities)
            learner._last_metrics = metrics
            window_updates += 1
            window_samples += int(batch.arrays["indices"].shape[0])
            learner.env_steps = int(batch.info.get("transitions_inserted", learner.env_steps))
            if learner.step % config.publish_every == 0:
                learner.version += 1
                publisher.publish(learner.agent.weights(), learner.version, learner.step, learner.env_steps)
            if learner.step % config.log_every == 0:
                elapsed = time.monotonic() - window_start
                learner._rates = {"updates_per_s": window_updates / elapsed, "samples_per_s": window_samples / elapsed}
                window_start, window_updates, window_samples = time.monotonic(), 0, 0
                metrics_log.write(learner.step, {**metrics, **learner._rates, "weights_version": learner.version,
                                                 **{f"replay_{k}": v for k, v in batch.info.items()}})
            if learner.step % config.checkpoint_every == 0:
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
