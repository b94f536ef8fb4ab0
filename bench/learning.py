"""Learning curves: train C2F-ARM on a task under a wall-clock budget, then plot eval success.

    python bench/learning.py --task reach_target --minutes 60 [--preset cpu-small] [--set k=v ...]

Runs the whole distributed system (``c2farm launch``) as it would run for a user, stops it
after the budget, and turns ``runs/<id>/metrics/eval.csv`` into ``learning_curve.csv`` and
``learning_curve.png`` (success vs env steps and vs minutes) in the run directory.
"""

from __future__ import annotations

import argparse
import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path


def plot(run_dir: Path) -> Path | None:
    """Write learning_curve.csv/.png from the evaluator's eval.csv; returns the PNG path."""
    source = run_dir / "metrics" / "eval.csv"
    if not source.exists():
        print(f"no evaluations recorded in {source}")
        return None
    rows = list(csv.DictReader(source.open()))
    start = float(rows[0]["time"]) if rows else 0.0
    launch_file = run_dir / "launched_at"
    if launch_file.exists():
        start = float(launch_file.read_text())
    curve = [
        {
            "minutes": (float(r["time"]) - start) / 60,
            "env_steps": int(float(r["env_steps"])),
            "learner_step": int(float(r["learner_step"])),
            "weights_version": int(float(r["weights_version"])),
            "success_rate": float(r["success_rate"]),
            "episodes": int(float(r["episodes"])),
        }
        for r in rows
    ]
    out_csv = run_dir / "learning_curve.csv"
    with out_csv.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(curve[0]))
        writer.writeheader()
        writer.writerows(curve)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for ax, x, label in ((a, "env_steps", "environment steps (decisions)"), (b, "minutes", "wall-clock minutes")):
        # A weights version published before the learner saw a batch carries no env-step count.
        points = [c for c in curve if x != "env_steps" or c["env_steps"] or not c["learner_step"]]
        ax.plot([c[x] for c in points], [100 * c["success_rate"] for c in points], marker="o")
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    counts = sorted({c["episodes"] for c in curve})
    a.set_ylabel(f"greedy eval success (%), {'/'.join(map(str, counts))} episodes per point")
    a.set_ylim(-2, 102)
    fig.suptitle(run_dir.name)
    fig.tight_layout()
    out_png = run_dir / "learning_curve.png"
    fig.savefig(out_png, dpi=110)
    for c in curve:
        print(f"{c['minutes']:7.1f} min  {c['env_steps']:7d} env steps  learner step {c['learner_step']:6d}  "
              f"success {100 * c['success_rate']:5.1f}%")
    return out_png


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="reach_target", help="task to learn")
    parser.add_argument("--minutes", type=float, default=60.0, help="wall-clock budget")
    parser.add_argument("--preset", default="cpu-small", help="config preset in configs/")
    parser.add_argument("--run-id", default=None, help="run id (default: learning-<task>-<time>)")
    parser.add_argument("--runs-dir", default="runs", help="where runs live")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    parser.add_argument("--plot-only", action="store_true", help="only (re)plot an existing run")
    args = parser.parse_args()
    run_id = args.run_id or f"learning-{args.task}-{time.strftime('%Y%m%d-%H%M%S')}"
    run_dir = Path(args.runs_dir) / run_id
    if not args.plot_only:
        cmd = [sys.executable, "-m", "deploy.cli", "launch", "--preset", args.preset, "--task", args.task,
               "--run-id", run_id, "--set", f"run.runs_dir={args.runs_dir}"]
        for item in args.set:
            cmd += ["--set", item]
        print("+", " ".join(cmd), flush=True)
        proc = subprocess.Popen(cmd, start_new_session=True)
        try:
            proc.wait(timeout=args.minutes * 60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    plot(run_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
