"""How a run's greedy evaluation episodes ended, per weights version: the first thing to read when a curve swings.

    python bench/eval_endings.py runs/<run-id>            # every evaluated version
    python bench/eval_endings.py runs/<run-id> --last 6   # the newest six

Reads the evaluator's recorded episodes (``runs/<id>/eval/v<version>-seed<seed>.mcap``) and
prints, per version: episodes, successes, how the others ended (timeout, unreachable with the
control agent's reason, failed), how many ended on an unreachable first pose, decisions per episode,
the share of next-best poses with the gripper closed, and the median x-y-z of the first pose. A
policy that flips between two places for the same scenes shows as a first pose that jumps between
versions; one that never grasps or never lets go shows in the closed share; one that skips an
approach for the grasp itself often ends on its first pose, out of the arm's collision-free reach.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol.episode_file import DemoFileError, read_episode_view  # noqa: E402

NAME = re.compile(r"v(\d+)-seed(\d+)\.mcap$")


def endings(paths: list[Path]) -> dict[str, object]:
    """One version's episodes summarised."""
    ends: Counter[str] = Counter()
    decisions, closed, firsts, unreachable_first = [], [], [], 0
    for path in paths:
        try:
            ep = read_episode_view(path)
        except DemoFileError as exc:
            ends["unreadable"] += 1
            print(f"  {path.name}: {exc}", file=sys.stderr)
            continue
        reason = ep.end_reason or ("success" if ep.success else "?")
        ends[f"{reason}:{ep.unreachable_reason}" if ep.unreachable_reason else reason] += 1
        decisions.append(len(ep.actions))
        unreachable_first += bool(ep.unreachable_reason) and len(ep.actions) == 1  # the first pose itself
        closed += [float(a[7] < 0.5) for a in ep.actions]
        if ep.actions:
            firsts.append(ep.actions[0][:3])
    first = np.median(np.stack(firsts), 0) if firsts else None
    return {"episodes": sum(ends.values()), "ends": ends, "decisions": statistics.fmean(decisions) if decisions else 0,
            "closed": statistics.fmean(closed) if closed else 0.0, "first": first,
            "unreachable_first": unreachable_first}


def recorded_episodes(run_dir: Path) -> dict[int, list[Path]]:
    """The evaluator's episode files of a run, by weights version (bench/greedy_keyframes.py reads them too)."""
    by_version: dict[int, list[Path]] = defaultdict(list)
    for path in sorted((run_dir / "eval").glob("v*-seed*.mcap")):
        match = NAME.search(path.name)
        if match:
            by_version[int(match.group(1))].append(path)
    return dict(by_version)


def episode_seed(path: Path) -> int:
    """The scene seed an evaluation episode file is named with."""
    return int(NAME.search(path.name).group(2))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="runs/<run-id> (its eval/ folder holds the episodes)")
    parser.add_argument("--last", type=int, default=0, help="only the newest N versions (0: all)")
    args = parser.parse_args()
    by_version = recorded_episodes(args.run_dir)
    if not by_version:
        print(f"no evaluation episodes under {args.run_dir / 'eval'} (actor.record_eval off?)", file=sys.stderr)
        return 1
    versions = sorted(by_version)[-args.last:] if args.last > 0 else sorted(by_version)
    print("| version | episodes | success | other endings | unreachable first pose | decisions | gripper closed "
          "| first pose x, y, z (median) |")
    print("|---|---|---|---|---|---|---|---|")
    for v in versions:
        s = endings(by_version[v])
        ends: Counter[str] = s["ends"]  # type: ignore[assignment]
        others = ", ".join(f"{n} {k}" for k, n in ends.most_common() if k != "success") or "-"
        first = "-" if s["first"] is None else ", ".join(f"{x:.3f}" for x in s["first"])
        print(f"| {v} | {s['episodes']} | {ends['success']} | {others} | {s['unreachable_first']} | "
              f"{s['decisions']:.1f} | {100 * s['closed']:.0f} % | {first} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
