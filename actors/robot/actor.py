"""The robot actor (``c2farm robot``): the actor loop on a real arm, with a person giving reward.

It is the simulated actor with another environment: the same weights following, the same
cascade and exploration, the same outbox and episode protocol, so the learner and the replay
need no change. Differences: a ``RobotEnv`` (arm, cameras, operator) instead of ``PandaEnv``;
episodes carry ``info["source"] = "robot"``; an operator stop pauses the loop until "resume"
and drops the cut-short episode; the policy picks poses in the robot's own depth-0 box
(``robot.scene_bounds``), which every observation carries to the learner. With
``robot.evaluate`` it also plays the evaluator's greedy episodes, into ``metrics/eval.csv``.
``robot.arm: franky-sim`` starts franky-sim inside this process (loopback, MuJoCo cameras),
so CI drives the very code that drives a real arm. With ``actor.foxglove_port`` (``--foxglove``)
the arm's scene and every decision's attention are served live to Foxglove (actors/live_view.py).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
import zlib
from dataclasses import dataclass
from typing import Callable, TextIO

import torch

from actors.actor_loop import ActingPolicy, Rollout, episode_seed, rollout, to_episode
from actors.config import ActorConfig
from actors.environment import Env
from actors.evaluation import EvalResult, append_eval_row, evaluate, live_view, watched, write_snapshot
from actors.robot.config import RobotConfig
from actors.robot.connect import open_env
from actors.robot.env import OperatorStopped
from actors.robot.operator import FabricOperator
from actors.role_loop import EpisodeStats, RoleLinks, first_episode_id
from protocol.messages import WeightsUpdate
from protocol.observation import Observation
from protocol.role import RoleContext
from qattention.cascade import ActResult
from qattention.config import QAttentionConfig

log = logging.getLogger("robot")


@dataclass
class RobotSetup:
    """What the robot actor role is told (``run(setup, ctx)``)."""

    actor: ActorConfig  #: acting, exploration, outbox and evaluation settings (shared with the simulated actor)
    robot: RobotConfig  #: the arm, its cameras, safety limits and the operator
    task: str  #: the task's name, for episodes and the heartbeat
    network: QAttentionConfig  #: the Q-attention cascade, as the learner trains it
    terminal: TextIO | None = None  #: the operator's text stream (a terminal), if any


def run(setup: RobotSetup, ctx: RoleContext) -> int:
    """Collect real episodes until stopped (or ``max_episodes``); the operator may speak through ``setup.terminal``."""
    config, robot, task, terminal = setup.actor, setup.robot, setup.task, setup.terminal
    torch.set_num_threads(max(1, config.torch_threads))
    torch.manual_seed(ctx.seed + zlib.crc32(ctx.instance.encode()))
    qconfig = setup.network.replace(epsilon=config.epsilon, scene_bounds=robot.depth0_bounds)
    stats = EpisodeStats()
    dropped = {"operator_stops": 0}  # episodes an operator stop cut short (not sent)
    with contextlib.ExitStack() as stack:
        arm, channel, env = open_env(robot, task, qconfig.episode_length, ctx.stop, stack, terminal)
        live = stack.enter_context(live_view(config.foxglove_port))
        env, on_decision = watched(env, live)
        host = arm.config.host
        links = stack.enter_context(RoleLinks(ctx, qconfig, sends=config))
        fabric_operator = FabricOperator(links.session, ctx.run_id, ctx.instance, channel)
        stack.callback(fabric_operator.close)
        follower, outbox = links.follower, links.outbox
        policy = ActingPolicy(qconfig, follower, epsilon=config.epsilon_at)
        latest: EvalResult | None = None  # the newest greedy evaluation on this arm, for the heartbeat

        def counters() -> dict[str, float]:
            return {**stats.as_dict(), **dropped, **outbox.counters, **arm.counters, **arm.safety.counters(),
                    **channel.counters,
                    "outbox_pending": outbox.pending, "weights_version": policy.version, **follower.counters(),
                    "epsilon": policy.agent.config.epsilon, **(latest.counters() if latest else {}),
                    "operator_rejected": fabric_operator.rejected, "paused": float(channel.paused),
                    "stop_to_still_s": arm.last_stop_s}

        links.beat("robot", counters, info=lambda: {"task": task, "arm": robot.arm, "host": host})
        policy.wait_for_first(config.weights_wait_s, ctx.stop)
        evaluated, next_evaluation = 0, 0.0
        first_id, n = first_episode_id(), 0
        while not ctx.stop.is_set() and not (config.max_episodes and n >= config.max_episodes):
            policy.refresh()
            adopted = policy.adopted
            if (robot.evaluate and adopted is not None and time.monotonic() >= next_evaluation
                    and evaluation_due(adopted.version, evaluated, config)):
                started = time.monotonic()
                try:
                    result = evaluate_here(env, policy, config, qconfig, adopted, ctx, on_decision)
                    if result is not None:
                        latest, evaluated = result, adopted.version
                        next_evaluation = training_resumes_until(started, time.monotonic(), robot.eval_share)
                except OperatorStopped as why:
                    log.info("evaluation dropped: %s", why)
                    channel.wait_resumed(ctx.stop)
                continue
            episode_id = first_id + n
            seed = episode_seed(ctx.seed, ctx.instance, episode_id)
            try:
                r = rollout(env, policy.agent, qconfig.cameras, seed, explore=True, stop=ctx.stop,
                            on_decision=on_decision, **config.acting_rules())
            except OperatorStopped as why:
                dropped["operator_stops"] += int(channel.paused)
                log.info("episode dropped: %s", why)
                channel.wait_resumed(ctx.stop)
                continue
            if r is None:
                break
            episode = to_episode(r, ctx.instance, episode_id, task, seed, policy.version)
            episode.info.update({"source": "robot", "arm": robot.arm})
            outbox.send(episode)
            outbox.resend_due()
            n += 1
            stats.add(r)
            log.info("episode %d: %s after %d decisions (weights v%d)", n, r.reason, len(r.actions), policy.version)
        outbox.flush(timeout_s=2.0)
    return 0


def evaluation_due(version: int, evaluated: int, config: ActorConfig) -> bool:
    """As the evaluator: the first weights, then a version at least ``eval_every_versions`` newer."""
    return not evaluated or version >= evaluated + config.eval_every_versions or version < evaluated


def training_resumes_until(started: float, ended: float, share: float) -> float:
    """When the next evaluation may start: evaluations take at most ``share`` of the arm's time.

    The simulated evaluator runs beside the actors; here one arm does both, and a learner that
    publishes faster than an evaluation lasts would otherwise keep it evaluating.
    """
    return ended + (ended - started) * (1.0 - share) / share


def evaluate_here(env: Env, policy: ActingPolicy, config: ActorConfig, qconfig: QAttentionConfig,
                  update: WeightsUpdate, ctx: RoleContext,
                  on_decision: Callable[[Observation, ActResult], None] | None = None) -> EvalResult | None:
    """The evaluator's greedy episodes on this arm, appended to ``metrics/eval.csv``; None if stopped part-way.

    A run with a robot has no simulated evaluator, so this is its learning curve (the
    dashboard's charts and bench/robot_learning.py read that file). Greedy episodes are
    measured, not sent to the replay, as the evaluator's.
    """
    record = ctx.run_dir / "eval" if config.record_eval else None
    first: list[Rollout] = []
    result = evaluate(env, policy, config, qconfig.cameras, record, ctx.stop, on_first=first.append,
                      on_decision=on_decision)
    if result is None:
        return None
    success, mean_return, unreachable, n = result
    if first:
        write_snapshot(ctx.run_dir / "eval", policy, first[0], env.task_name, config.eval_seed, update)
    (ctx.run_dir / "metrics").mkdir(parents=True, exist_ok=True)
    done = EvalResult(update.version, update.learner_step, update.env_steps, n, success, mean_return, unreachable)
    append_eval_row(ctx.run_dir / "metrics" / "eval.csv", done)
    log.info("greedy evaluation of weights v%d: success %.0f%% over %d episodes, %.0f%% unreachable",
             update.version, 100 * success, n, 100 * unreachable)
    return done


def terminal_stream():
    """The operator's terminal: this process's stdin when it is a terminal, else none."""
    return sys.stdin if sys.stdin is not None and sys.stdin.isatty() else None
