"""``c2farm export policy RUN_DIR --out DIR``: a run's trained policy as a folder that acts without the run.

It reads the run's ``config.yaml`` (the network and how observations were made) and a learner
checkpoint (the newest that reads back whole and finite, or ``--checkpoint``), keeps only the
weights acting uses and writes them with the facts acting needs (``protocol/policy_file.py``).
The weights are those the run's actors acted with: the online networks, or their average
when the run published one (``learner.acting_average``); the optimiser and the target
networks stay behind. Before writing, they are loaded into the cascade the config describes,
so a policy that would not fit is refused here rather than on a robot.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import torch

from deploy.config_loader import ConfigError, to_dict
from learner.checkpoint import MARKER, UNREADABLE, load_checkpoint, load_latest
from protocol.policy_file import PolicyFile, PolicyFileError, write_policy


class ExportError(ValueError):
    """Why a policy cannot be exported; one line."""


def export_command(args) -> int:
    """Write the policy; one line and exit code 2 when the run or the checkpoint cannot give one."""
    try:
        policy = policy_from_run(Path(args.run_dir), Path(args.checkpoint) if args.checkpoint else None)
        out = write_policy(Path(args.out), policy)
    except (ExportError, PolicyFileError, ConfigError) as exc:
        print(f"c2farm: export policy: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"c2farm: export policy: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    size = sum(t.numel() * t.element_size() for t in policy.tensors.values())
    print(f"c2farm export policy: {out} ({len(policy.tensors)} tensors, {size / 1e6:.1f} MB): policy "
          f"v{policy.version} (learner step {policy.learner_step}) of {policy.task}, {policy.config['weights']} "
          f"weights; try `c2farm eval --policy {out}`")
    return 0


def policy_from_run(run_dir: Path, checkpoint: Path | None = None) -> PolicyFile:
    """The policy of ``run_dir`` at ``checkpoint`` (default: its newest usable learner checkpoint)."""
    from deploy import config as cfg_mod
    from deploy.roles import network_config
    from qattention.agent import C2FARM
    from qattention.digest import network_digest

    config_path = run_dir / "config.yaml"
    if not config_path.is_file():
        raise ExportError(f"{run_dir}: not a run directory (no config.yaml; runs are under runs/<run-id>/)")
    config = cfg_mod.load_config(preset=None, files=(config_path,))
    if checkpoint is None:
        root = run_dir / "checkpoints" / "learner"
        state = load_latest(root)
        if state is None:
            raise ExportError(f"{root}: no complete, readable learner checkpoint (has the learner run and "
                              "checkpointed? it writes one every learner.checkpoint_every updates and on stop)")
    else:
        state = read_checkpoint(checkpoint)
    tensors, source = acting_weights(state, config.learner.acting_average)
    qconfig = network_config(config)
    try:
        C2FARM(qconfig).load_weights(tensors)
    except ValueError as exc:
        raise ExportError(f"the checkpoint's networks do not fit the run's config.yaml: {exc}") from None
    return PolicyFile(tensors, {
        "task": config.sim.task,
        "cameras": list(qconfig.cameras),
        "scene_bounds": list(qconfig.scene_bounds),
        "qattention": json.loads(json.dumps(qconfig.to_dict())),
        "network_digest": network_digest(qconfig),
        "weights": source,
        "weights_version": int(state["version"]),
        "learner_step": int(state["step"]),
        "env_steps": int(state.get("env_steps", 0)),
        "sim": json.loads(json.dumps(to_dict(config.sim))),
        "actor": {"reachable_top_k": config.actor.reachable_top_k, "skip_repeats": config.actor.skip_repeats,
                  "eval_seed": config.actor.eval_seed},
        "run_id": config.run.run_id,
        "exported_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "code": {k: v for k, v in cfg_mod.versions().items() if k in ("c2farm", "git_commit", "git_dirty", "torch")},
    })


def acting_weights(state: dict[str, Any], acting_average: float) -> tuple[dict[str, torch.Tensor], str]:
    """The online networks out of a learner state, or their average where the run acted with it; and which."""
    agent = state.get("agent")
    if not isinstance(agent, dict):
        raise ExportError("the checkpoint holds no agent state")
    online = {k: t for k, t in agent.items() if k.startswith("net.") and isinstance(t, torch.Tensor)}
    if not online:
        raise ExportError("the checkpoint's agent state holds no online networks (net.*)")
    average = state.get("acting_average") or {}
    if acting_average > 0 and average.keys() == online.keys():
        return {k: average[k].to(online[k].dtype) for k in online}, "acting_average"
    return online, "online"


def read_checkpoint(path: Path) -> dict[str, Any]:
    """One learner checkpoint (its ``step-N`` folder, or the ``tensors.safetensors`` in it), checked whole."""
    folder = path.parent if path.is_file() else path
    if not (folder / MARKER).is_file():
        raise ExportError(f"{path}: not a complete learner checkpoint (expected a step-N folder with "
                          f"tensors.safetensors, state.json and {MARKER})")
    try:
        state = load_checkpoint(folder)
    except UNREADABLE as exc:
        raise ExportError(f"{folder}: unreadable checkpoint ({' '.join(str(exc).split())[:200]})") from None
    if not isinstance(state, dict) or not {"agent", "step", "version"} <= state.keys():
        raise ExportError(f"{folder}: not a learner checkpoint (no agent, step and version)")
    return state
