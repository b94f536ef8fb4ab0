"""``c2farm robot --policy DIR``: the robot actor's greedy evaluation, with weights from an exported policy.

The arm, its cameras, the operator and ``RobotEnv`` are the robot actor's (actor.py); what
differs is where the weights come from (a policy file, not the weights follower) and that
nothing joins a run: no Zenoh session, no episodes sent, so it needs no router and no
learner. The operator speaks through the terminal (or, on franky-sim with
``robot.scripted_operator``, the scripted reach check), as for ``c2farm robot``. An operator
stop drops the evaluation in progress; it starts over once resumed, so the rate printed is
always over whole, unpaused episodes. ``actor.foxglove_port`` (``--foxglove``) serves the arm's
scene and every decision's attention live to Foxglove, as the evaluator does.
"""

from __future__ import annotations

import contextlib
import logging
import threading

import torch

from actors.evaluation import evaluate, live_view, watched
from actors.policy_eval import PolicyEvaluation, fixed_policy, result_of
from actors.robot.actor import RobotSetup
from actors.robot.connect import open_env
from actors.robot.env import OperatorStopped
from protocol.policy_file import PolicyFile

log = logging.getLogger("robot")


def run_policy(setup: RobotSetup, policy: PolicyFile, stop: threading.Event) -> PolicyEvaluation | None:
    """``setup.actor.eval_episodes`` greedy episodes on the arm with ``policy``; None when stopped first."""
    config, robot = setup.actor, setup.robot
    torch.set_num_threads(max(1, config.torch_threads))
    qconfig = setup.network.replace(epsilon=0.0, scene_bounds=robot.depth0_bounds)  # as the robot actor: its own box
    fixed = fixed_policy(policy, qconfig)
    with contextlib.ExitStack() as stack:
        _, channel, env = open_env(robot, setup.task, qconfig.episode_length, stop, stack, setup.terminal)
        live = stack.enter_context(live_view(config.foxglove_port))
        env, on_decision = watched(env, live)
        if setup.terminal is None and not robot.scripted_operator:
            log.warning("no terminal and no scripted operator: nobody here can say reset done, success or fail "
                        "(episodes wait for them); run it in a terminal")
        while not stop.is_set():
            try:
                outcome = evaluate(env, fixed, config, qconfig.cameras, None, stop, on_decision=on_decision)
            except OperatorStopped as why:
                log.info("evaluation dropped (%s); it starts over once resumed", why)
                channel.wait_resumed(stop)
                continue
            return None if outcome is None else result_of(outcome, setup.task, fixed)
    return None
