"""Where a trained run's greedy episodes go wrong: each decision beside the demo's keyframes, and where things rest.

    python bench/greedy_trace.py runs/<run-id> [--episodes 20]

Loads the run's newest learner checkpoint with the weights its evaluator acted with (the online
weights' average where the run used one) and plays the evaluator's seeds as it does (greedy, the
same reachable top-K). For each seed it first records the scripted demo, for its keyframe poses
and for where the object the demo grasps comes to rest. Per greedy decision it prints the gripper
command, whether the hand holds the object, the nearest demo keyframe with its distance, and the
gripper's value margin ``g`` (open's value less closed's: how sure the gripper head was); per
episode, how it ended and where the object rests against the demo's resting place. The summary
sorts the failures: never grasped, still held at the end, let go off the demo's place (by how
much), unreachable. A plateau whose failures all let go a few centimetres off is a precision
problem; one that never grasps is not.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from trained_run import load_trained_run  # noqa: E402  (bench/trained_run.py)


def graspables(task) -> list[tuple[str, int]]:
    """The task's graspable (body name, link) pairs: names, because a reset spawns the bodies anew."""
    names = {body: name for name, body in task.bodies.items()}
    return [(names[body], link) for body, link in task.graspables()]


def demo_reference(env, seed: int):
    """The scripted demo on ``seed``: its success, keyframe poses [K, 8], the object it grasps and where that rests.

    The object is the graspable nearest the demo's first closed-gripper keyframe in the reset scene.
    """
    from actors.demos.augmentation import keyframe_action
    from actors.demos.generate import record_demo
    from actors.demos.keyframes import demo_keyframes

    env.reset(seed)
    start = {obj: env.task.pose_of(*obj)[0] for obj in graspables(env.task)}
    demo = record_demo(env, seed)
    keyframes = np.stack([keyframe_action(demo.observations[k]) for k in demo_keyframes(demo)])
    closed = [pose for pose in keyframes if pose[7] < 0.5]
    grasp = closed[0][:3] if closed else keyframes[-1, :3]
    obj = min(start, key=lambda o: float(np.linalg.norm(start[o] - grasp))) if start else None
    return demo.success, keyframes, obj, (env.task.pose_of(*obj)[0] if obj is not None else None)


def trace(run, seed: int, env, out=print) -> dict:
    """One greedy episode on ``seed`` next to its demo; returns how it ended and the object's rest offset (m)."""
    from actors.actor_loop import rollout

    demo_ok, keyframes, obj, demo_rest = demo_reference(env, seed)
    held_ever = False
    lines: list[str] = []

    def on_decision(obs, act) -> None:
        nonlocal held_ever
        pose = np.asarray(act.action[0])
        gaps = np.linalg.norm(keyframes[:, :3] - pose[:3], axis=1)
        k = int(np.argmin(gaps))
        held = env.scene.grasped is not None
        held_ever |= held
        moved_on = " (moved on)" if act.repeat_skipped is not None and act.repeat_skipped[0] else ""
        shut_q, open_q = act.gripper_q[0]
        lines.append(f"{'open' if pose[7] > 0.5 else 'shut'}{'+held' if held else ''} k{k + 1} {100 * gaps[k]:.1f}"
                     f" g{open_q - shut_q:+.2f}{moved_on}")

    r = rollout(env, run.agent, run.qconfig.cameras, seed, explore=False,
                on_decision=on_decision, **run.config.actor.acting_rules())
    held_ever |= env.scene.grasped is not None
    if r.success:
        kind = "success"
    elif r.reason == "unreachable":
        kind = f"unreachable ({r.unreachable_reason})"
    elif not held_ever:
        kind = "never grasped"
    elif env.scene.grasped is not None:
        kind = "still held at the end"
    else:
        kind = "let go, no success"
    offset = env.task.pose_of(*obj)[0] - demo_rest if obj is not None else None
    rest = "" if offset is None else " ({:+.1f}, {:+.1f}, {:+.1f}) cm from the demo's rest".format(*100 * offset)
    out(f"seed {seed} ({'demo ok' if demo_ok else 'demo FAILED'}, {len(keyframes)} keyframes): {kind}{rest}")
    out("    " + " | ".join(lines))
    return {"kind": kind, "offset": offset, "seed": seed}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="runs/<run-id> with config.yaml and checkpoints/learner")
    parser.add_argument("--episodes", type=int, default=20, help="evaluation seeds to play")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="change the run's config for the replay, e.g. actor.skip_repeats=true (repeatable)")
    args = parser.parse_args(argv)

    from actors.panda_env import PandaEnv
    from deploy.config_loader import ConfigError

    try:
        run = load_trained_run(args.run_dir, acting=True, overrides=tuple(args.set))
    except ConfigError as exc:  # a --set the run's config refuses: one line, before any episode
        parser.error(f"--set: {exc}")
    if run is None:
        return 1
    env = PandaEnv(run.config.sim)
    print(f"{run.config.sim.task}, learner step {run.step}, acting weights; per decision: gripper (+held when "
          f"the hand holds something), the nearest demo keyframe and its distance (cm), g: open's value less "
          f"closed's, '(moved on)' where a repeat "
          f"of the gripper's pose gave way (actor.skip_repeats)" + (f"; with {' '.join(args.set)}" if args.set else ""))
    ends = []
    try:
        for seed in range(run.config.actor.eval_seed, run.config.actor.eval_seed + args.episodes):
            ends.append(trace(run, seed, env))
    finally:
        env.close()
    kinds = Counter(e["kind"] for e in ends)
    print("endings: " + ", ".join(f"{n} {k}" for k, n in kinds.most_common()))
    for kind in kinds:
        gaps = [float(np.linalg.norm(e["offset"])) for e in ends if e["kind"] == kind and e["offset"] is not None]
        if gaps:
            print(f"  {kind}: the object rests a median {100 * statistics.median(gaps):.1f} cm from the demo's "
                  f"(range {100 * min(gaps):.1f}-{100 * max(gaps):.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
