"""A finished (or running) run's networks as the learner last saved them, for the diagnosis benches."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass
class TrainedRun:
    config: Any  #: the run's resolved config (runs/<id>/config.yaml)
    qconfig: Any  #: its Q-attention config, as the learner built it
    agent: Any  #: a C2FARM on the CPU with the newest complete learner checkpoint loaded
    step: int  #: that checkpoint's learner step


def load_trained_run(run_dir: Path, acting: bool = False, overrides: tuple[str, ...] = ()) -> TrainedRun | None:
    """The run's config and newest learner checkpoint; None (after saying so) if it has none.

    ``acting`` loads the weights the actors and the evaluator acted with: the online weights' average
    where the run published one (``learner.acting_average``), else the online weights. ``overrides``
    (``section.key=value``, as ``--set`` takes them) change the run's config, e.g. an acting rule to try
    on the same weights; they must leave the network as it was trained.
    """
    import torch

    from deploy.config import load_config
    from deploy.config_loader import parse_override
    from deploy.roles import network_config
    from learner.checkpoint import load_latest
    from qattention.agent import C2FARM

    torch.set_num_threads(1)
    config = load_config(preset=None, files=(run_dir / "config.yaml",),
                         overrides=tuple(parse_override(text) for text in overrides))
    qconfig = network_config(config)
    state = load_latest(run_dir / "checkpoints" / "learner")
    if state is None:
        print(f"no complete learner checkpoint under {run_dir / 'checkpoints' / 'learner'}")
        return None
    agent = C2FARM(qconfig, device="cpu")
    agent.load_state_dict(state["agent"])
    if acting and config.learner.acting_average > 0 and state.get("acting_average"):
        from learner.acting_average import ActingAverage

        average = ActingAverage(config.learner.acting_average)
        average.load_state_dict(state["acting_average"])
        agent.load_weights(average.weights(agent.weights()))
    return TrainedRun(config, qconfig, agent, int(state["step"]))
