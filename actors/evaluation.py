"""The evaluator: the greedy policy on a fixed, seeded set of episodes, once per weights version.

The same seeds for every version make the success rates comparable along the run; the
results go to the dashboard (heartbeat counters) and to ``runs/<id>/metrics/eval.csv``.
Each episode is recorded under ``runs/<id>/eval/`` as MCAP (frames, executed next-best poses,
why it ended), and the first decision of the first episode as a Q-attention snapshot
(``eval/qattention-latest.npz``, actors/qattention_snapshot.py) for the dashboard.
"""

from __future__ import annotations

import contextlib
import csv
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch

from actors.actor_loop import ActingPolicy, Rollout, rollout
from actors.config import ActorConfig
from actors.role_loop import ActingSetup, RoleLinks
from protocol.observation import Observation
from protocol.role import RoleContext
from qattention.cascade import ActResult

log = logging.getLogger("eval")

EVAL_FIELDS = ["time", "weights_version", "learner_step", "env_steps", "episodes", "success_rate", "mean_return",
               "unreachable_rate"]


@dataclass
class EvalResult:
    weights_version: int
    learner_step: int
    env_steps: int
    episodes: int
    success_rate: float
    mean_return: float
    unreachable_rate: float  #: episodes that ended on a pose the arm could not reach

    def counters(self) -> dict[str, float]:
        """The latest evaluation as heartbeat counters (the dashboard's summary and progress line)."""
        return {"eval_success": self.success_rate, "eval_episodes": self.episodes, "eval_return": self.mean_return,
                "eval_unreachable": self.unreachable_rate, "eval_version": self.weights_version,
                "eval_env_steps": self.env_steps}


def evaluate(env, policy: ActingPolicy, config: ActorConfig, cameras, record_dir: Path | None = None, stop=None,
             on_first: Callable[[Rollout], None] | None = None,
             on_decision: Callable[[Observation, ActResult], None] | None = None,
             ) -> tuple[float, float, float, int] | None:
    """Greedy rollouts on seeds ``eval_seed, eval_seed + 1, ...``: (success, return, unreachable, n).

    Runs ``eval_episodes``, or only ``eval_min_episodes`` when none of those succeeded (a 0 %
    point needs fewer episodes to be sure of). None when stopped part-way: a partial result
    would bias the curve. ``on_first`` is handed the first episode (the Q-attention snapshot),
    ``on_decision`` every decision as it is made (``rollout``'s; the live view).
    """
    if record_dir is not None:
        record_dir.mkdir(parents=True, exist_ok=True)
    successes, returns, unreachable, done = 0, 0.0, 0, 0
    for i in range(config.eval_episodes):
        if done >= config.eval_min_episodes and not successes:
            break
        if stop is not None and stop.is_set():
            return None
        r = rollout(env, policy.agent, cameras, config.eval_seed + i, explore=False, stop=stop,
                    on_decision=on_decision, **config.acting_rules())
        if r is None:
            return None
        successes += int(r.success)
        returns += r.total_reward
        unreachable += int(r.reason == "unreachable")
        done += 1
        if i == 0 and on_first is not None:
            on_first(r)
        if record_dir is not None:
            from protocol.episode_file import write_episode_mcap

            write_episode_mcap(record_dir / f"v{policy.version:06d}-seed{config.eval_seed + i}.mcap",
                               r.observations, task=env.task_name, seed=config.eval_seed + i, success=r.success,
                               actions=r.actions, end_reason=r.reason, unreachable_reason=r.unreachable_reason)
    return successes / done, returns / done, unreachable / done, done


def run(setup: ActingSetup, ctx: RoleContext) -> int:
    """Evaluate each new weights version (at most one every ``eval_every_versions``) until stopped."""
    from actors.panda_env import PandaEnv

    config, sim_config, qconfig = setup.actor, setup.sim, setup.network
    torch.set_num_threads(max(1, config.torch_threads))
    latest: EvalResult | None = None
    csv_path = ctx.run_dir / "metrics" / "eval.csv"
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    board = _tensorboard(ctx.run_dir / "tensorboard") if config.eval_tensorboard else None
    evaluations = evaluated_version = 0
    with contextlib.closing(PandaEnv(sim_config)) as bare, RoleLinks(ctx, qconfig) as links, \
            live_view(config.foxglove_port) as live:
        env, on_decision = watched(bare, live)
        follower = links.follower
        policy = ActingPolicy(qconfig.replace(epsilon=0.0), follower)

        def counters() -> dict[str, float]:
            return {"evaluations": evaluations, **follower.counters(), **(latest.counters() if latest else {})}

        heartbeat = links.beat("eval", counters, info=lambda: {"task": sim_config.task})
        try:
            while not ctx.stop.is_set():
                follower.fetch_latest(timeout_s=2.0)
                update = follower.newer()
                if update is not None and update.version < evaluated_version:
                    evaluated_version = 0  # resynced below a version the learner never announced: start afresh
                if update is None or (evaluated_version
                                      and update.version < evaluated_version + config.eval_every_versions):
                    ctx.stop.wait(2.0)
                    continue
                if not follower.adopt(update, policy.agent.load_weights):
                    continue  # did not fit the networks (counted by the follower)
                record = ctx.run_dir / "eval" if config.record_eval else None
                first: list[Rollout] = []
                result = evaluate(env, policy, config, qconfig.cameras, record, ctx.stop, on_first=first.append,
                                  on_decision=on_decision)
                if result is None:
                    break  # stopped mid-evaluation
                if first:
                    write_snapshot(ctx.run_dir / "eval", policy, first[0], env.task_name, config.eval_seed, update)
                success, mean_return, unreachable, n = result
                evaluated_version = update.version
                evaluations += 1
                latest = EvalResult(update.version, update.learner_step, update.env_steps, n, success, mean_return,
                                    unreachable)
                append_eval_row(csv_path, latest)
                if board is not None:
                    for name, value in (("success_rate", success), ("mean_return", mean_return),
                                        ("unreachable_rate", unreachable)):
                        board.add_scalar(f"eval/{name}", value, update.learner_step)
                    board.flush()
                log.info("weights v%d (step %d, %d env steps): success %.0f%% over %d episodes",
                         update.version, update.learner_step, update.env_steps, 100 * success, n)
                heartbeat.publish()
        finally:
            if board is not None:
                board.close()
    return 0


@contextlib.contextmanager
def live_view(port: int):
    """The scene served live to Foxglove on ``port`` (:mod:`actors.live_view`); None when ``port`` is -1.

    Also None, with a warning, when the port is taken (``c2farm launch --robot --foxglove`` starts
    an evaluator and a robot actor that both ask for it): a viewer never stops a role.
    """
    if port < 0:
        yield None
        return
    from actors.live_view import LiveView

    try:
        live = LiveView(port=port)
    except RuntimeError as exc:  # foxglove's FoxgloveError: the port is in use
        log.warning("no live view for Foxglove on port %d (%s); --foxglove 0 picks a free port", port, exc)
        yield None
        return
    with live:
        log.info("live view for Foxglove at ws://127.0.0.1:%d (Open connection, Foxglove WebSocket)", live.port)
        yield live


def watched(env, live):
    """(env, on_decision) for ``rollout``/``evaluate``: shown on ``live`` (a LiveView) when there is one, else as
    they are (no decision hook)."""
    return (live.wrap(env), live.show_decision) if live else (env, None)


def write_snapshot(directory: Path, policy: ActingPolicy, first: Rollout, task: str, seed: int, update) -> None:
    """The first decision of ``first`` as ``qattention-latest.npz``; a failure is logged, never fatal."""
    from actors.qattention_snapshot import compute_snapshot
    from protocol.attention_snapshot import FILENAME, save_snapshot

    try:
        meta = {"weights_version": update.version, "learner_step": update.learner_step, "env_steps": update.env_steps,
                "task": task, "seed": seed, "time": time.time(), "end": first.reason}
        action = first.actions[0] if first.actions else None
        save_snapshot(directory / FILENAME, compute_snapshot(policy.agent, first.observations[0], action, meta=meta))
    except Exception:  # the dashboard's picture must never stop an evaluation
        log.exception("could not write the Q-attention snapshot")


def _tensorboard(directory: Path):
    """A SummaryWriter in the learner's TensorBoard directory (its own event file), or None."""
    try:
        from torch.utils.tensorboard import SummaryWriter

        return SummaryWriter(str(directory), filename_suffix=".eval")
    except Exception:  # TensorBoard missing or the directory unwritable: the CSV still has it all
        log.exception("no TensorBoard for evaluations")
        return None


def append_eval_row(path: Path, result: EvalResult) -> None:
    """One evaluation as a row of ``metrics/eval.csv`` (header first in a new file); the robot actor writes it too."""
    new = not path.exists()
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=EVAL_FIELDS)
        if new:
            writer.writeheader()
        writer.writerow({"time": time.time(), **result.__dict__})
