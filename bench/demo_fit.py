"""Can the cascade learn where and at what yaw to grasp from the demos alone? Fit on N demos, test on unseen scenes.

    python bench/demo_fit.py --task pick_and_lift --demos 10 --updates 200 --yaw-augmentation 0,45

Records ``--demos`` scripted demos (seeds from 0) and ``--held-out`` unseen scenes (the
evaluator's seeds), then for each variant trains a fresh cascade (the preset's networks, same
seed) on the demos' keyframe transitions only, no environment, and every ``--eval-every``
updates prints the greedy first pose's error against the scripted first waypoint on the unseen
scenes: x-y distance, yaw error, and yaw error modulo ``--yaw-symmetry`` (90 for a cube, whose
four faces grasp alike). The "constant yaw" row is what a policy that ignores the object scores.
It isolates the imitation half of learning, minutes per variant instead of an hour per seed.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def wrap(degrees: np.ndarray, period: float) -> np.ndarray:
    """Absolute angle difference folded into [0, period / 2]."""
    d = np.mod(degrees, period)
    return np.minimum(d, period - d)


def demo_transitions(env, count: int, every_n: int):
    """(obs, action, reward, terminal, next_obs) tuples of the keyframe episodes of ``count`` successful demos."""
    from actors.demos.augmentation import demo_to_transitions
    from actors.demos.generate import record_demo
    from actors.demos.keyframes import demo_keyframes

    rows, used = [], []
    for seed in range(3 * count):
        demo = record_demo(env, seed)
        if not demo.success:
            continue
        used.append(seed)
        for ep in demo_to_transitions(demo.observations, demo_keyframes(demo), every_n=every_n):
            for t in range(len(ep.actions)):
                rows.append((ep.observations[t], ep.actions[t], ep.rewards[t], ep.terminals[t], ep.observations[t + 1]))
        if len(used) == count:
            break
    return rows, used


def by_keyframe(rows, values) -> dict[int, list]:
    """``values`` (one per row of ``demo_transitions(..., every_n=10**9)``) grouped by keyframe index in their demo."""
    out, k = defaultdict(list), 0
    for row, value in zip(rows, values):
        out[k].append(value)
        k = 0 if row[3] else k + 1  # a terminal row ends its demo
    return out


def keyframe_actions(env, seed: int) -> list[np.ndarray]:
    """The next-best poses a demo of scene ``seed`` teaches: its keyframes' actions, in order."""
    from actors.demos.augmentation import demo_to_transitions
    from actors.demos.generate import record_demo
    from actors.demos.keyframes import demo_keyframes

    demo = record_demo(env, seed)
    first = demo_to_transitions(demo.observations, demo_keyframes(demo), every_n=10**9)[0]
    return [np.asarray(a) for a in first.actions]


def batch_of(rows, cameras, bounds):
    import torch

    from qattention.batch import ObservationBatch, TransitionBatch

    obs = ObservationBatch.from_observations([r[0] for r in rows], cameras, scene_bounds=bounds)
    nxt = ObservationBatch.from_observations([r[4] for r in rows], cameras, scene_bounds=bounds)
    n = len(rows)
    return TransitionBatch(
        obs=obs, next_obs=nxt,
        action=torch.as_tensor(np.stack([r[1] for r in rows]), dtype=torch.float32),
        reward=torch.as_tensor([float(r[2]) for r in rows]),
        terminal=torch.as_tensor([bool(r[3]) for r in rows]),
        is_demo=torch.ones(n, dtype=torch.bool),
        weights=torch.ones(n),
    )


def quaternion_yaws(actions) -> np.ndarray:
    """Yaw (degrees, extrinsic xyz Euler as the rotation bins use) of each pose [.., 8]'s quaternion."""
    import torch

    from qattention.rotation import quaternion_to_euler

    q = torch.as_tensor(np.stack([a[3:7] for a in actions]), dtype=torch.float64)
    return quaternion_to_euler(q)[..., 2].numpy()


def first_pose_errors(agent, test_obs, demo_actions, symmetry: float):
    """Median x-y error (cm), median yaw error, median yaw error modulo ``symmetry`` (degrees), greedy yaws."""
    greedy = np.asarray(agent.act(test_obs).action)
    yaws = quaternion_yaws(greedy)
    dyaw = yaws - quaternion_yaws(demo_actions)
    xy = np.linalg.norm(greedy[:, :2] - np.stack(demo_actions)[:, :2], axis=1) * 100
    return float(np.median(xy)), float(np.median(wrap(dyaw, 360))), float(np.median(wrap(dyaw, symmetry))), yaws


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="pick_and_lift")
    parser.add_argument("--preset", default="cpu-small")
    parser.add_argument("--demos", type=int, default=10, help="training demos")
    parser.add_argument("--held-out", type=int, default=20, help="unseen scenes to test the first pose on")
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument("--eval-every", type=int, default=50)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--yaw-augmentation", default="0,45", help="comma-separated demo_yaw_augmentation values")
    parser.add_argument("--yaw-symmetry", type=float, default=90.0, help="yaw period of the grasped object")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rollouts", type=int, default=0,
                        help="after training, play this many greedy episodes on the unseen scenes through the "
                        "control agent and say where each ended against the scripted waypoints")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="config override (e.g. a ladder entry's cameras and grid)")
    args = parser.parse_args()

    import torch

    from actors.panda_env import PandaEnv
    from deploy.config import load_config
    from deploy.config_loader import parse_override
    from deploy.roles import network_config
    from qattention.agent import C2FARM
    from qattention.batch import ObservationBatch

    torch.manual_seed(args.seed)
    config = load_config(preset=args.preset, overrides=({"sim": {"task": args.task}},
                                                                   *map(parse_override, args.set)))
    qconfig = network_config(config)
    cams, bounds = qconfig.cameras, qconfig.scene_bounds
    env = PandaEnv(config.sim)
    t0 = time.perf_counter()
    rows, used = demo_transitions(env, args.demos, config.demos.every_n)
    tests, scripted = [], []
    for seed in range(config.actor.eval_seed, config.actor.eval_seed + args.held_out):
        obs = env.reset(seed=seed)
        tests.append((obs, np.asarray(env.demo_waypoints()[0].action())))
        if len(scripted) < args.rollouts:
            scripted.append(keyframe_actions(env, seed))
    demo_actions = [t[1] for t in tests]
    test_obs = ObservationBatch.from_observations([t[0] for t in tests], cams, scene_bounds=bounds)
    demo_yaw = quaternion_yaws(demo_actions)
    const = float(np.median(wrap(demo_yaw - statistics.median(demo_yaw), args.yaw_symmetry)))
    print(f"{args.task}: {len(used)} demos (seeds {used}), {len(rows)} keyframe transitions, "
          f"{len(tests)} unseen scenes, recorded in {time.perf_counter() - t0:.0f} s; "
          f"preset {args.preset}, batch {args.batch}, torch threads {torch.get_num_threads()}")
    print(
        f"constant yaw (the unseen scenes' median) scores a median yaw error mod {args.yaw_symmetry:g} "
        f"of {const:.1f} deg"
    )
    print("| yaw augmentation (deg) | updates | s/update | x-y error (cm, median) | yaw error (deg) | "
          f"yaw error mod {args.yaw_symmetry:g} (deg) | distinct greedy yaws |")
    print("|---|---|---|---|---|---|---|")
    for aug in (float(a) for a in args.yaw_augmentation.split(",")):
        agent = C2FARM(qconfig.replace(demo_yaw_augmentation=aug), seed=args.seed)
        rng = np.random.default_rng(args.seed)
        spent = 0.0
        for u in range(1, args.updates + 1):
            pick = rng.choice(len(rows), args.batch, replace=len(rows) < args.batch)
            start = time.perf_counter()
            agent.update(batch_of([rows[i] for i in pick], cams, bounds))
            spent += time.perf_counter() - start
            if u % args.eval_every == 0 or u == args.updates:
                xy, dyaw, dmod, yaws = first_pose_errors(agent, test_obs, demo_actions, args.yaw_symmetry)
                print(f"| {aug:g} | {u} | {spent / u:.2f} | {xy:.1f} | {dyaw:.1f} | {dmod:.1f} | "
                      f"{len(set(np.round(yaws, 1)))} |", flush=True)
        if args.rollouts:
            greedy_rollouts(env, agent, config, cams, scripted[: args.rollouts])
    env.close()
    return 0


def greedy_rollouts(env, agent, config, cameras, scripted: list[list[np.ndarray]]) -> None:
    """Play the imitation-only policy greedily on the unseen scenes; print how far each decision was from
    the demo keyframe of the same index (what the demos teach), and how the episodes ended."""
    from collections import Counter

    from actors.actor_loop import rollout

    ends, per_decision = Counter(), {}
    for i, waypoints in enumerate(scripted):
        r = rollout(env, agent, cameras, config.actor.eval_seed + i, explore=False,
                    **config.actor.acting_rules())
        ends[f"{r.reason}{'/' + r.unreachable_reason if r.unreachable_reason else ''} at {len(r.actions)}"] += 1
        for t, (action, waypoint) in enumerate(zip(r.actions, waypoints)):
            row = per_decision.setdefault(t, [[], 0])
            row[0].append(float(np.linalg.norm(action[:3] - waypoint[:3])) * 100)
            row[1] += int(round(float(action[7])) == round(float(waypoint[7])))
    print(f"greedy rollouts ({len(scripted)} unseen scenes): "
          + ", ".join(f"{k}: {v}" for k, v in sorted(ends.items())))
    print("| decision | episodes reaching it | distance to the demo keyframe (cm, median) | gripper as the demo |")
    print("|---|---|---|---|")
    for t, (dist, same) in sorted(per_decision.items()):
        print(f"| {t + 1} | {len(dist)} | {statistics.median(dist):.1f} | {same}/{len(dist)} |")


if __name__ == "__main__":
    raise SystemExit(main())
