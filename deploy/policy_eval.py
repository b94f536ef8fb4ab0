"""``c2farm eval --policy DIR`` and ``c2farm robot --policy DIR``: an exported policy's greedy success rate.

No run directory, no router, no other role: the policy folder says what the run knew (the
network, the task, how observations were rendered, the evaluator's seeds) and the resolved
config adds the rest (the arm, acting threads). ``--task`` evaluates on another task than the
policy's; ``--episodes N`` runs exactly N episodes; ``--set actor.KEY=...`` wins over what the
policy carries from its run.
"""

from __future__ import annotations

import dataclasses
import sys
import threading

from actors.sim.task_specs import TASKS
from deploy.config import RunConfig
from deploy.config_loader import ConfigError, from_dict, parse_override
from protocol.policy_file import PolicyFile, PolicyFileError, read_policy
from protocol.role import stop_on_signals


def policy_command(args, config: RunConfig) -> int:
    """Evaluate ``args.policy`` in simulation (eval) or on the configured arm (robot); print the success line."""
    from actors.policy_eval import evaluate_in_sim, network_of

    try:
        policy = read_policy(args.policy)
        network = network_of(policy)
        task = args.task or policy.task
        actor = acting_config(policy, config, args)
        if args.command == "eval" and task not in TASKS:
            raise ConfigError(f"--task: unknown task {task!r}; choose from {', '.join(TASKS)}")
        stop = threading.Event()
        stop_on_signals(stop)  # Ctrl-C ends the episode in progress, and with it the evaluation
        if args.command == "eval":
            result = evaluate_in_sim(policy, sim_config(policy, task), actor, stop)
        else:
            from actors.robot.actor import RobotSetup, terminal_stream
            from actors.robot.policy_actor import run_policy

            result = run_policy(RobotSetup(actor, config.robot, task, network, terminal_stream()), policy, stop)
    except (PolicyFileError, ConfigError) as exc:
        print(f"c2farm: {args.command} --policy: {exc}", file=sys.stderr)
        return 2
    if result is None:
        print(f"c2farm: {args.command} --policy: stopped before the evaluation finished", file=sys.stderr)
        return 1
    print(result.line(), flush=True)
    return 0


def acting_config(policy: PolicyFile, config: RunConfig, args):
    """The resolved actor section, with the policy's run's evaluation settings unless ``--set actor.*`` names them,
    and ``--episodes`` episodes exactly (none cut short for a 0 % start)."""
    explicit = {key for text in args.overrides for key in parse_override(text).get("actor", {})}
    carried = {k: v for k, v in policy.config.get("actor", {}).items()
               if k not in explicit and k in {f.name for f in dataclasses.fields(config.actor)}}
    episodes = args.episodes if args.episodes is not None else config.actor.eval_episodes
    if episodes < 1:
        raise ConfigError(f"--episodes must be >= 1 (got {episodes})")
    try:
        return dataclasses.replace(config.actor, **carried, eval_episodes=episodes, eval_min_episodes=episodes,
                                   record_eval=False)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"actor: {exc}") from None


def sim_config(policy: PolicyFile, task: str):
    """The simulator as the policy's run rendered it (image size, cameras, control), on ``task``."""
    from actors.sim.config import SimConfig

    sim = policy.config.get("sim", {"cameras": policy.config["cameras"]})
    if not isinstance(sim, dict):
        raise PolicyFileError(f"config.json: field 'sim' must be an object, got {sim!r:.60}")
    try:
        return from_dict(SimConfig, {**sim, "task": task, "cameras": policy.config["cameras"]})
    except ConfigError as exc:
        raise PolicyFileError(f"config.json: sim: {exc}") from None
