"""Can the arm do what the cascade can say? Each demo's keyframe poses, snapped to the grid, executed again.

    python bench/keyframes_executed.py --tasks lift_lid put_in_bin --episodes 40
    python bench/keyframes_executed.py --tasks lift_lid --set qattention.voxel_size=8

A task whose greedy policy stays at 0 % may not be a learning problem at all. For every
evaluation seed (the evaluator's, from ``actor.eval_seed``) this records the scripted demo,
recovers its keyframes by the reference rule, and replays the keyframe poses from home in a
freshly reset scene, four ways:

* ``demo``: the scripted waypoints themselves (the demo's own success);
* ``keyframes``: the recovered keyframe poses, as the demo augmentation labels them;
* ``snapped``: those poses as the cascade can express them: translation through the voxel
  grid of every depth, rotation through the Euler bins (the preset's ``qattention``);
* ``snapped-direct``: the same without the first keyframe when it only approaches (gripper
  open and unchanged), what a greedy policy that learnt "grasp straight from home" does.

Each prints its success count and, for the failures, the first unreachable reason (with the
keyframe it hit) or ``no success`` when every pose was executed. A variant that fails here
cannot be learnt: fix the task, the scene or the control agent before the learner.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VARIANTS = ("demo", "keyframes", "snapped", "snapped-direct")


def snap(actions: np.ndarray, qconfig) -> np.ndarray:
    """Poses [N, 8] as the cascade would act them: voxel centres of the last depth, rotation-bin centres."""
    import torch

    from qattention.action_codec import decode_action, encode_action

    bounds = torch.tensor(qconfig.scene_bounds, dtype=torch.float32)
    labels = encode_action(torch.as_tensor(actions, dtype=torch.float32), bounds, qconfig)
    return decode_action(labels.voxel_indices, labels.rot_grip, bounds, qconfig).numpy()


def direct(actions: np.ndarray) -> np.ndarray:
    """Drop the first keyframe when it is an approach: the gripper open there and at the start (no change)."""
    if len(actions) > 1 and actions[0, 7] > 0.5:
        return actions[1:]
    return actions


def execute(env, seed: int, actions: np.ndarray) -> str:
    """Reset to ``seed`` and step the poses; "success", "<reason> at keyframe k" or "no success"."""
    env.reset(seed)
    for k, action in enumerate(actions):
        result = env.step(action)
        if result.unreachable:
            return f"{result.info.get('reason', 'unreachable')} at keyframe {k}"
        if result.success:
            return "success"
    return "no success"


def run_task(config, episodes: int) -> dict[str, Counter]:
    from actors.demos.augmentation import keyframe_action
    from actors.demos.generate import record_demo
    from actors.demos.keyframes import demo_keyframes
    from actors.panda_env import PandaEnv
    from deploy.roles import network_config

    qconfig = network_config(config)
    env = PandaEnv(config.sim)
    outcomes = {v: Counter() for v in VARIANTS}
    lengths = Counter()
    try:
        for seed in range(config.actor.eval_seed, config.actor.eval_seed + episodes):
            demo = record_demo(env, seed)
            outcomes["demo"]["success" if demo.success else "no success"] += 1
            keyframes = demo_keyframes(demo)
            lengths[len(keyframes)] += 1
            actions = np.stack([keyframe_action(demo.observations[k]) for k in keyframes])
            for variant, poses in (("keyframes", actions), ("snapped", snap(actions, qconfig)),
                                   ("snapped-direct", direct(snap(actions, qconfig)))):
                outcomes[variant][execute(env, seed, poses)] += 1
    finally:
        env.close()
    outcomes["keyframes per demo"] = lengths
    return outcomes


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", required=True, help="tasks of the ladder")
    parser.add_argument("--episodes", type=int, default=40, help="evaluation seeds per task")
    parser.add_argument("--preset", default="cpu-small", help="config preset in configs/ (its qattention grid)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    args = parser.parse_args(argv)

    from actors.sim.task_specs import TASKS
    from deploy.config import load_config
    from deploy.config_loader import parse_override

    unknown = [t for t in args.tasks if t not in TASKS]
    if unknown:
        parser.error(f"unknown task(s) {', '.join(unknown)}; choose from {', '.join(TASKS)}")
    for task in args.tasks:
        config = load_config(args.preset, overrides=(*map(parse_override, args.set), {"sim": {"task": task}}))
        q = config.qattention
        print(f"## {task}: {args.episodes} evaluation seeds, grid {q.depths} x {q.voxel_size}^3, "
              f"offset {q.bounds_offset}, {q.rotation_resolution} deg bins", flush=True)
        for variant, counts in run_task(config, args.episodes).items():
            detail = ", ".join(f"{n} {what}" for what, n in counts.most_common())
            print(f"  {variant:18s} {detail}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
