"""Scripted demos per task: success rate over N seeds (no cameras, physics + control only), then, for a
few episodes with cameras, demo generation time and MCAP bytes per episode.

    .venv/bin/python bench/bench_demos.py --seeds 100 --record-episodes 2
"""

from __future__ import annotations

import argparse
import tempfile
import time

from actors.demos.generate import generate_demos, record_demo
from actors.panda_env import PandaEnv
from actors.sim import TASKS, SimConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--tasks", default=",".join(TASKS), help="comma-separated tasks")
    ap.add_argument("--seeds", type=int, default=100, help="seeds per task for the success rate")
    ap.add_argument("--record-episodes", type=int, default=2, help="episodes per task recorded to MCAP (4 cameras)")
    ap.add_argument("--cameras", default="front,left_shoulder,right_shoulder,wrist", help="cameras when recording")
    args = ap.parse_args()
    print(
        "| task | demo success | seeds | s/episode (no cameras) | s/episode recorded (4 cams, MCAP) "
        "| frames/episode | MB/episode |"
    )
    print("|---|---|---|---|---|---|---|")
    for task in args.tasks.split(","):
        env = PandaEnv(SimConfig(task=task, cameras=()))
        ok, t0, frames = 0, time.perf_counter(), 0
        failed = []
        for s in range(args.seeds):
            d = record_demo(env, s)
            ok += d.success
            frames += len(d.observations)
            if not d.success:
                failed.append(s)
        per_ep = (time.perf_counter() - t0) / args.seeds
        env.close()
        rec = mb = "-"
        if args.record_episodes:
            with tempfile.TemporaryDirectory() as out:
                summ = generate_demos(task, args.record_episodes, 1000, out, cameras=tuple(args.cameras.split(",")),
                                      progress=False)
                rec = f"{summ.seconds / args.record_episodes:.1f}"
                mb = f"{summ.bytes / args.record_episodes / 1e6:.1f}"
        print(
            f"| {task} | {ok}/{args.seeds} ({100 * ok / args.seeds:.0f}%) | 0..{args.seeds - 1} | {per_ep:.2f} "
            f"| {rec} | "
            f"{frames / args.seeds:.0f} | {mb} |",
            flush=True,
        )
        if failed:
            print(f"<!-- {task} failed seeds: {failed} -->", flush=True)


if __name__ == "__main__":
    main()
