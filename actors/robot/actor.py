"""The robot actor (``c2farm robot``): the actor loop on a real arm, with a person giving reward.

It is the simulated actor with another environment: the same weights following, the same
cascade and exploration, the same outbox and episode protocol, so the learner and the replay
need no change. Differences: a ``RobotEnv`` (arm, cameras, operator) instead of ``PandaEnv``;
episodes carry ``info["source"] = "robot"``; an operator stop pauses the loop until "resume"
and drops the cut-short episode; the policy picks poses in the robot's own depth-0 box
(``robot.scene_bounds``), which every observation carries to the learner. With
``robot.evaluate`` it also plays the evaluator's greedy episodes, into ``metrics/eval.csv``.
``robot.arm: franky-sim`` starts franky-sim inside this process (loopback, MuJoCo cameras),
so CI drives the very code that drives a real arm.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import sys
import time
import zlib

import torch

from actors.actor_loop import ActingPolicy, Rollout, episode_seed, rollout, to_episode
from actors.config import ActorConfig
from actors.evaluation import EvalResult, evaluate, write_snapshot
from actors.evaluation import append_eval_row
from actors.outbox import Outbox
from actors.robot.config import RobotConfig
from actors.robot.env import OperatorStopped, ReachOperator, RobotEnv
from actors.robot.franka import FrankaArm
from actors.robot.operator import FabricOperator, OperatorChannel, TerminalOperator
from actors.weights import WeightsFollower
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.messages import WeightsUpdate
from protocol.role import RoleContext
from qattention.config import QAttentionConfig
from qattention.digest import network_digest

log = logging.getLogger("robot")


def make_cameras(robot: RobotConfig, sim, stack: contextlib.ExitStack) -> list:
    """The configured cameras: RealSense devices, or renders of the franky-sim scene."""
    cameras = []
    for cam in robot.cameras:
        if cam.kind == "mujoco":
            if sim is None:
                raise ValueError(f"camera {cam.name}: kind mujoco needs robot.arm franky-sim")
            cameras.append(sim.camera(cam.name, cam.image_size))
        else:
            from actors.robot.cameras import load_extrinsics
            from actors.robot.realsense import RealSenseCamera

            if not cam.extrinsics_file:
                raise ValueError(f"camera {cam.name}: a RealSense camera needs extrinsics_file (camera-to-base YAML)")
            camera = RealSenseCamera(cam.name, load_extrinsics(cam.extrinsics_file), cam.serial, cam.image_size)
            stack.callback(camera.close)
            cameras.append(camera)
    return cameras


def open_arm(robot: RobotConfig, stack: contextlib.ExitStack):
    """(connected arm, franky-sim or None): the configured arm with its cameras, closed by ``stack``.

    ``robot.arm: franky-sim`` starts franky-sim in this process first (loopback, MuJoCo cameras).
    """
    sim = None
    if robot.arm == "franky-sim":
        from actors.robot.franky_sim import FrankySim, SimSceneConfig

        sim = stack.enter_context(FrankySim(SimSceneConfig(cameras=tuple(c.name for c in robot.cameras))))
    host = sim.hostname if sim is not None else robot.franka.host
    arm = FrankaArm(dataclasses.replace(robot.franka, host=host), robot.safety, make_cameras(robot, sim, stack))
    arm.connect()
    stack.callback(arm.disconnect)
    return arm, sim


def run(config: ActorConfig, robot: RobotConfig, task: str, qconfig: QAttentionConfig, ctx: RoleContext,
        terminal=None) -> int:
    """Collect real episodes until stopped (or ``max_episodes``); ``terminal`` is the operator's text stream."""
    torch.set_num_threads(max(1, config.torch_threads))
    torch.manual_seed(ctx.seed + zlib.crc32(ctx.instance.encode()))
    qconfig = qconfig.replace(epsilon=config.epsilon, scene_bounds=robot.depth0_bounds)
    stats = {"episodes": 0, "env_steps": 0, "successes": 0, "unreachable": 0, "timeouts": 0, "operator_stops": 0,
             "reach_checks": 0, "reach_replaced": 0}
    with contextlib.ExitStack() as stack:
        arm, sim = open_arm(robot, stack)
        host = arm.config.host
        channel = OperatorChannel(on_stop=arm.stop, on_resume=arm.resume)
        session = open_session(ctx.fabric)
        stack.callback(session.close)
        fabric_operator = FabricOperator(session, ctx.run_id, ctx.instance, channel)
        stack.callback(fabric_operator.close)
        if terminal is not None:
            operator = stack.enter_context(TerminalOperator(terminal, channel))  # restores the terminal on the way out
            print(operator.help, flush=True)
        scripted = ReachOperator(sim, channel) if robot.scripted_operator else None
        env = RobotEnv(arm, channel, robot, task, qconfig.episode_length, ctx.stop, scripted)
        follower = WeightsFollower(session, ctx.run_id, network_digest(qconfig))
        stack.callback(follower.close)
        policy = ActingPolicy(qconfig, follower, epsilon=config.epsilon_at)
        outbox = Outbox(session, ctx.run_id, ctx.instance, config.outbox_size, config.resend_after_s,
                        config.outbox_wait_s, stop=ctx.stop)
        stack.callback(outbox.close)
        latest: EvalResult | None = None  # the newest greedy evaluation on this arm, for the heartbeat

        def counters() -> dict[str, float]:
            return {**stats, **outbox.counters, **arm.counters, **arm.safety.counters(), **channel.counters,
                    "outbox_pending": outbox.pending, "weights_version": policy.version, **follower.counters(),
                    "epsilon": policy.agent.config.epsilon, **(latest.counters() if latest else {}),
                    "operator_rejected": fabric_operator.rejected, "paused": float(channel.paused), "stop_to_still_s": arm.last_stop_s,
                    "success_rate": stats["successes"] / max(1, stats["episodes"])}

        heartbeat = Heartbeat(session, ctx.run_id, "robot", ctx.instance, counters=counters,
                              info=lambda: {"task": task, "arm": robot.arm, "host": host})
        stack.callback(heartbeat.close)
        policy.wait_for_first(config.weights_wait_s, ctx.stop)
        evaluated, next_evaluation = 0, 0.0
        first_id, n = int(time.time() * 1000), 0
        while not ctx.stop.is_set() and not (config.max_episodes and n >= config.max_episodes):
            policy.refresh()
            adopted = policy.adopted
            if (robot.evaluate and adopted is not None and time.monotonic() >= next_evaluation
                    and evaluation_due(adopted.version, evaluated, config)):
                started = time.monotonic()
                try:
                    result = evaluate_here(env, policy, config, qconfig, adopted, ctx)
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
                            top_k=config.reachable_top_k)
            except OperatorStopped as why:
                stats["operator_stops"] += int(channel.paused)
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
            stats["episodes"] += 1
            stats["env_steps"] += len(r.actions)
            stats["successes"] += int(r.success)
            stats["timeouts"] += int(r.timeout)
            stats["unreachable"] += int(r.reason == "unreachable")
            if r.unreachable_reason:
                stats[f"unreachable_{r.unreachable_reason}"] = stats.get(f"unreachable_{r.unreachable_reason}", 0) + 1
            stats["reach_checks"] += r.reach_checks
            stats["reach_replaced"] += r.reach_replaced
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


def evaluate_here(env: RobotEnv, policy: ActingPolicy, config: ActorConfig, qconfig: QAttentionConfig,
                  update: WeightsUpdate, ctx: RoleContext) -> EvalResult | None:
    """The evaluator's greedy episodes on this arm, appended to ``metrics/eval.csv``; None if stopped part-way.

    A run with a robot has no simulated evaluator, so this is its learning curve (the
    dashboard's charts and bench/robot_learning.py read that file). Greedy episodes are
    measured, not sent to the replay, as the evaluator's.
    """
    record = ctx.run_dir / "eval" if config.record_eval else None
    first: list[Rollout] = []
    result = evaluate(env, policy, config, qconfig.cameras, record, ctx.stop, on_first=first.append)
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
