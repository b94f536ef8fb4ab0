"""Which scripted keyframe each greedy decision went for, and at which keyframe the unreachable episodes stopped.

    python bench/greedy_keyframes.py runs/<run-id>                    # every recorded evaluation episode
    python bench/greedy_keyframes.py runs/<run-id> --from-version 190 # the later ones only

Reads the evaluator's recorded episodes (``runs/<id>/eval/v<version>-seed<seed>.mcap``, their next-best
poses) and rebuilds each episode's scene from its seed to get the task's scripted waypoints (the demo's
keyframes; no demo is played, nothing is learnt). Each greedy pose is named after the nearest keyframe
(``k<i>`` with ``o``/``c`` for the gripper it asked for), so an episode reads as a sequence such as
``k1o k2c``: the handle's approach, then its grasp. It prints the commonest sequences with how they
ended, then per keyframe the poses nearest it: how many ended their episode on an unreachable pose, and
the median offset of those and of the others from the keyframe (cm, in the keyframe's own frame, so
"+z" is along the hand's approach, deeper into what it grasps) and their rotation off it. A policy short of the bar on a
long task shows here where it stops: at an empty-air approach, or one voxel too deep into a handle.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_endings import episode_seed, recorded_episodes  # noqa: E402  (bench/eval_endings.py)

from dashboard.episodes import quaternion_matrix  # noqa: E402
from protocol.episode_file import DemoFileError, EpisodeView, read_episode_view  # noqa: E402


def rotation_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    """Angle between two hand orientations (quaternions xyzw), a half turn about the approach axis folded away:
    the parallel gripper grasps the same either way round."""
    r = quaternion_matrix(q1).T @ quaternion_matrix(q2)
    angles = []
    for flip in (np.eye(3), np.diag([-1.0, -1.0, 1.0])):
        cos = (np.trace(r @ flip) - 1) / 2
        angles.append(float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))))
    return min(angles)


def nearest_keyframe(pose: np.ndarray, keyframes: np.ndarray) -> int:
    """Index of the keyframe [K, 8] whose position is nearest the pose's."""
    return int(np.argmin(np.linalg.norm(keyframes[:, :3] - pose[:3], axis=1)))


def offset_in_keyframe(pose: np.ndarray, keyframe: np.ndarray) -> np.ndarray:
    """The pose's position less the keyframe's, in the keyframe's frame (cm)."""
    return 100 * quaternion_matrix(keyframe[3:7]).T @ (pose[:3] - keyframe[:3])


def scene_keyframes(task: str, seeds: list[int]) -> dict[int, np.ndarray]:
    """Each seed's scripted waypoints [K, 8], from its scene rebuilt in the simulator (one wrist camera)."""
    from actors.panda_env import PandaEnv
    from actors.sim import SimConfig

    env = PandaEnv(SimConfig(task=task, cameras=("wrist",), image_size=32))
    try:
        out = {}
        for seed in seeds:
            env.reset(seed)
            out[seed] = np.stack([w.action() for w in env.demo_waypoints()])
        return out
    finally:
        env.close()


def read_episodes(run_dir: Path, from_version: int = 0) -> list[tuple[int, EpisodeView]]:
    """(seed, episode view) of every recorded evaluation episode with next-best poses, from ``from_version`` on."""
    episodes = []
    for version, paths in sorted(recorded_episodes(run_dir).items()):
        for path in paths if version >= from_version else ():
            try:
                ep = read_episode_view(path)
            except DemoFileError as exc:
                print(f"  {path.name}: {exc}", file=sys.stderr)
                continue
            if len(ep.actions):
                episodes.append((episode_seed(path), ep))
    return episodes


def by_keyframe(episodes: list[tuple[int, EpisodeView]]) -> tuple[Counter, dict[int, dict[str, list]]]:
    """The episodes' (ending, keyframe sequence) counts, and per keyframe index the poses nearest it as
    (x, y, z offset in cm, rotation in degrees), split into those that ended their episode unreachable
    ("stopped") and the rest ("went on")."""
    keyframes = scene_keyframes(episodes[0][1].task, sorted({seed for seed, _ in episodes}))
    sequences: Counter[tuple[str, str]] = Counter()
    near: dict[int, dict[str, list]] = defaultdict(lambda: {"stopped": [], "went on": []})
    for seed, ep in episodes:
        kf = keyframes[seed]
        names = []
        for i, pose in enumerate(np.asarray(ep.actions, float)):
            k = nearest_keyframe(pose, kf)
            names.append(f"k{k + 1}{'o' if pose[7] > 0.5 else 'c'}")
            stopped = i == len(ep.actions) - 1 and bool(ep.unreachable_reason)
            near[k]["stopped" if stopped else "went on"].append(
                (*offset_in_keyframe(pose, kf[k]), rotation_deg(pose[3:7], kf[k][3:7])))
        sequences[(ep.end_reason or "?", " ".join(names))] += 1
    return sequences, dict(near)


def median_row(rows: list) -> str:
    if not rows:
        return "-"
    m = np.median(np.asarray(rows), 0)
    return f"{m[0]:+.1f}, {m[1]:+.1f}, {m[2]:+.1f}; {m[3]:.0f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="runs/<run-id> (its eval/ folder holds the episodes)")
    parser.add_argument("--from-version", type=int, default=0, help="only weights versions from this one on")
    parser.add_argument("--sequences", type=int, default=15, help="how many of the commonest sequences to print")
    args = parser.parse_args()
    episodes = read_episodes(args.run_dir, args.from_version)
    if not episodes:
        print(f"no evaluation episodes with next-best poses under {args.run_dir / 'eval'}", file=sys.stderr)
        return 1
    sequences, near = by_keyframe(episodes)
    print(f"{len(episodes)} episodes from weights version {args.from_version} on\n")
    print("| episodes | ended | greedy poses by their nearest keyframe |\n|---|---|---|")
    for (end, seq), n in sequences.most_common(args.sequences):
        print(f"| {n} | {end} | {seq} |")
    print("\n| keyframe | poses nearest it | ended there unreachable | their offset x, y, z (cm); rotation (deg) "
          "| the others' offset; rotation |\n|---|---|---|---|---|")
    for k in sorted(near):
        stopped, went_on = near[k]["stopped"], near[k]["went on"]
        print(f"| k{k + 1} | {len(stopped) + len(went_on)} | {len(stopped)} | {median_row(stopped)} | "
              f"{median_row(went_on)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
