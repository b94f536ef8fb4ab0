"""bench/trained_run.py and bench/greedy_trace.py: a run's checkpoint acts with the weights its evaluator used."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import greedy_trace  # noqa: E402  (bench/greedy_trace.py)
from trained_run import load_trained_run  # noqa: E402  (bench/trained_run.py)

TINY = ("qattention.kernels=4", "qattention.head_width=16", "qattention.image_crop=16", "sim.image_size=32",
        "learner.acting_average=0.9", "sim.task=reach_target")


def finished_run(tmp_path: Path) -> Path:
    """A run dir as the learner leaves it: config.yaml, and a checkpoint whose acting average differs from its nets."""
    from deploy.config import load_config, write_run_dir
    from deploy.config_loader import parse_override
    from deploy.roles import network_config
    from learner.acting_average import ActingAverage
    from learner.checkpoint import save_checkpoint
    from qattention.agent import C2FARM

    overrides = (*map(parse_override, TINY), {"run": {"run_id": "trained", "runs_dir": str(tmp_path)}})
    config = load_config("cpu-small", overrides=overrides)
    run_dir = write_run_dir(config)
    agent = C2FARM(network_config(config), device="cpu", seed=0)
    average = ActingAverage(0.9)
    average.update({k: torch.zeros_like(t) for k, t in agent.weights().items()})  # an average of all-zero nets
    save_checkpoint(run_dir / "checkpoints" / "learner", 7, {"agent": agent.state_dict(), "step": 7,
                                                           "acting_average": average.state_dict()})
    return run_dir


def test_the_acting_weights_are_the_average_the_run_published(tmp_path):
    run_dir = finished_run(tmp_path)
    online = load_trained_run(run_dir)
    acting = load_trained_run(run_dir, acting=True)
    assert online.step == acting.step == 7
    assert any(t.abs().sum() > 0 for t in online.agent.weights().values())
    assert all(t.abs().sum() == 0 for t in acting.agent.weights().values())


def test_a_trace_plays_the_evaluators_seed_beside_its_demo(tmp_path):
    from actors.panda_env import PandaEnv

    run = load_trained_run(finished_run(tmp_path))
    env = PandaEnv(run.config.sim)
    lines: list[str] = []
    try:
        end = greedy_trace.trace(run, run.config.actor.eval_seed, env, out=lines.append)
    finally:
        env.close()
    assert end["kind"] in {"success", "never grasped"} or end["kind"].startswith("unreachable")
    assert lines[0].startswith(f"seed {run.config.actor.eval_seed} (demo ok")
    decisions = lines[1].strip().split(" | ")
    assert 1 <= len(decisions) <= run.qconfig.episode_length
    assert all(d.split()[0] in {"open", "shut"} for d in decisions)  # reach_target grasps nothing: never "+held"
    for d in decisions:  # the gripper head's margin agrees with the command it gave (greedy: no exploration)
        margin = float(d.split()[3].removeprefix("g"))
        assert margin >= 0 if d.split()[0] == "open" else margin <= 0


def test_a_set_the_config_refuses_is_one_line_before_any_episode(tmp_path, capsys):
    run_dir = finished_run(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        greedy_trace.main([str(run_dir), "--set", "actor.skip_repeat=true"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "Traceback" not in err
    assert err.splitlines()[-1].endswith("--set: actor.skip_repeat: unknown key (did you mean 'skip_repeats'?)")
