"""The paper's coarse-to-fine depth and voxel-size study, on lift_lid and put_in_bin, in one table.

    python bench/grid_study.py --task lift_lid --seeds 3                        # every grid, seeds interleaved
    python bench/grid_study.py --task lift_lid --seeds 1 --grids 8-8 16-16-16   # a first pass on two grids
    python bench/grid_study.py --task lift_lid --seeds 3 --summary --costs      # run nothing, time each update

C2F-ARM studies how many depths its cascade has and how many voxels a side each depth has on
take-lid and rubbish-in-bin, written (depth sizes): (16,16) is the paper's two depths of 16³ voxels,
(8,8,8) three depths of 8³. Fewer voxels make every update cheaper, the one lever that speeds up
every task on a CPU, but a coarse last depth cannot place the gripper finely enough. The study
answers which grid gets there first in wall-clock minutes on this machine.

Each grid is the task's ladder entry with only the grid changed (bench/ablation.py's ``lid-grid-*``
for lift_lid, ``release-grid-*`` for put_in_bin), each seed one ``bench/learning.py`` run stopped once
it holds the threshold, its curve in ``bench/results/<task>-<preset>-<entry>-grid-<grid>-s<seed>.csv``.
A seed whose CSV is there is not run again, so the command resumes and seeds run on other days combine;
the table holds every grid with a seed CSV, not only those named, and keeps the update costs timed before.

Writes ``bench/results/grid_study-<task>.{md,csv}``: per grid its voxels per depth, the last depth's
voxel edge, what an update costs (the updates per second each run achieved, and with ``--costs`` the
seconds per batch-8 update of the cpu-small cascade timed here on one thread), then each seed's
minutes, env steps and updates to the threshold, the worst seed first. The grids are ordered by their
worst seed's minutes: the first is the one to choose for this CPU.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
from pathlib import Path
from typing import Optional, Sequence

import learning  # bench/learning.py: the arguments every learning bench takes
import learning_curves  # bench/learning_curves.py
from ablation import GRIDS, LEVERS, grid_name, learning_args  # bench/ablation.py: the grid levers of each entry

#: The study's tasks and the ladder entry each grid is swapped into (bench/ablation.py's ENTRY_LEVERS).
ENTRIES = {"lift_lid": "lid", "put_in_bin": "release"}
CSV_FIELDS = ["grid", "voxels", "last_voxel_cm", "update_s", "seed", "minutes", "env_steps", "updates",
              "final_success", "minutes_run", "updates_per_s"]


def grid_config(task: str, grid: str):
    """The resolved Q-attention config of one grid of the study."""
    from deploy.config import load_config
    from deploy.config_loader import parse_override

    overrides = tuple(parse_override(o) for o in LEVERS[variant(task, grid)])
    return load_config("cpu-small", overrides=(*overrides, {"sim": {"task": task}})).qattention


def variant(task: str, grid: str) -> str:
    return f"{ENTRIES[task]}-grid-{grid}"


def seed_csv(args: argparse.Namespace, grid: str, seed: int) -> Path:
    return Path(args.results_dir) / f"{args.task}-{args.preset}-{variant(args.task, grid)}-s{seed}.csv"


def seed_row(grid: str, seed: int, curve: learning_curves.Curve, threshold: float) -> dict:
    """One seed: when it first reached the threshold (None: not in its budget) and how fast it updated."""
    point = learning_curves.first_reaching(curve, threshold)
    last = curve[-1]
    return {
        "grid": grid, "seed": seed,
        "minutes": point and round(point["minutes"], 2), "env_steps": point and point["env_steps"],
        "updates": point and point["learner_step"], "final_success": last["success_rate"],
        "minutes_run": round(last["minutes"], 2),
        "updates_per_s": round(last["learner_step"] / (60 * last["minutes"]), 3) if last["minutes"] else None,
    }


def worst(rows: Sequence[dict]) -> dict:
    """The seed that got there last; any seed that never got there is worse than every one that did."""
    return max(rows, key=lambda r: (r["minutes"] is None, r["minutes"] or 0.0, r["env_steps"] or 0))


def study_rows(args: argparse.Namespace, costs: dict[str, float]) -> dict[str, list[dict]]:
    """Per grid with any seed (named now or not), its seeds' rows, the worst first; grids by their worst seed's
    minutes."""
    by_grid = {}
    for grid in GRIDS:
        cfg = grid_config(args.task, grid)
        rows = []
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            path = seed_csv(args, grid, seed)
            if path.exists():
                rows.append(seed_row(grid, seed, learning_curves.read_curve_csv(path), args.threshold))
        for row in rows:
            suffix = grid.split("-")[-1]  # "8-8-8-fine": the same voxels as (8,8,8), a smaller last cube
            row.update(voxels=grid_name(cfg) + ("" if suffix.isdigit() else f" {suffix}"),
                       last_voxel_cm=round(100 * 2 * cfg.offset(cfg.depths - 1) / cfg.voxel_size, 2)
                       if cfg.depths > 1 else None,
                       update_s=costs.get(grid))
        if rows:
            w = worst(rows)
            by_grid[grid] = [w] + sorted((r for r in rows if r is not w), key=lambda r: r["seed"])
    return dict(sorted(by_grid.items(), key=lambda item: (item[1][0]["minutes"] is None,
                                                           item[1][0]["minutes"] or 0.0)))


def table(by_grid: dict[str, list[dict]], threshold: float) -> str:
    """Markdown: one line per seed, each grid's worst seed first (in bold), grids fastest first.

    A grid with fewer seeds can sit above one with more: its count is beside its name.
    """
    header = ["grid", "last voxel", "update (s, batch 8)", "updates/s in the run", "seed",
              f"first ≥ {100 * threshold:g} % (min, env steps, updates)", "final", "ran (min)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for grid, rows in by_grid.items():
        rates = [r["updates_per_s"] for r in rows if r["updates_per_s"]]
        for i, r in enumerate(rows):
            first = i == 0
            reached = ("not reached" if r["minutes"] is None
                       else f"{r['minutes']:.1f}, {r['env_steps']:,}, {r['updates']:,}")
            lines.append("| " + " | ".join([
                f"**{r['voxels']}**, {len(rows)} seed{'s' if len(rows) > 1 else ''}" if first else "",
                f"{r['last_voxel_cm']:.2f} cm" if first and r["last_voxel_cm"] else "",
                f"{r['update_s']:.2f}" if first and r["update_s"] else "",
                f"{statistics.median(rates):.2f}" if first and rates else "",
                f"{r['seed']}" + (" (worst)" if first and len(rows) > 1 else ""),
                f"**{reached}**" if first else reached,
                f"{100 * r['final_success']:.0f} %", f"{r['minutes_run']:.1f}"]) + " |")
    return "\n".join(lines)


def time_updates(grids: Sequence[str]) -> dict[str, float]:
    """Seconds per batch-8 update of the cpu-small cascade on each grid, one thread (bench/bench_qattention.py)."""
    import torch
    from bench_qattention import grid_cost

    torch.set_num_threads(1)
    costs = {}
    for grid in grids:
        costs[grid] = grid_cost(GRIDS[grid], torch.device("cpu"), 8)["update_s"]
        print(f"{grid}: {costs[grid]:.2f} s per update", flush=True)
    return costs


def recorded_costs(path: Path) -> dict[str, float]:
    """The update costs an earlier ``--costs`` wrote into the study's CSV (empty where none was timed)."""
    try:
        with path.open(newline="") as f:
            return {row["grid"]: float(row["update_s"]) for row in csv.DictReader(f) if row.get("update_s")}
    except (FileNotFoundError, KeyError, ValueError):
        return {}


def write_results(args: argparse.Namespace, costs: dict[str, float]) -> str:
    """The study's table and CSV: every grid with a seed CSV, the costs timed now or else those recorded."""
    results = Path(args.results_dir)
    by_grid = study_rows(args, {**recorded_costs(results / f"grid_study-{args.task}.csv"), **costs})
    learning_curves.write_csv(results / f"grid_study-{args.task}.csv",
                              [r for rows in by_grid.values() for r in rows], CSV_FIELDS)
    text = table(by_grid, args.threshold)
    missing = [g for g in args.grids if g not in by_grid]
    note = f"\n\nNo seed has run yet: {', '.join(missing)}." if missing else ""
    (results / f"grid_study-{args.task}.md").write_text(
        f"{args.task}, preset {args.preset}, its ladder entry with only the grid changed; seeds "
        f"{args.first_seed}-{args.first_seed + args.seeds - 1}, {args.minutes:g} min each, a run stopped once "
        f"{args.stop_held} evaluations in a row reached {100 * args.threshold:g} %.\n\n{text}{note}\n")
    return text + note


def parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="lift_lid", choices=list(ENTRIES), help="the study's task")
    parser.add_argument("--grids", nargs="+", default=list(GRIDS), metavar="GRID",
                        help=f"grids to compare (default: all of {', '.join(GRIDS)})")
    parser.add_argument("--minutes", type=float, default=30.0, help="wall-clock budget per seed")
    parser.add_argument("--threshold", type=float, default=0.8, help="the success rate timed, and held to stop")
    parser.add_argument("--stop-held", type=int, default=2, metavar="N", help="evaluations in a row to stop")
    learning.add_seed_arguments(parser, 3, "per grid")
    learning.add_place_arguments(parser)
    parser.add_argument("--summary", action="store_true", help="only read the per-seed CSVs and write the table")
    parser.add_argument("--costs", action="store_true", help="also time one update per grid here (~1 min)")
    args = parser.parse_args(argv)
    unknown = [g for g in args.grids if g not in GRIDS]
    if unknown:
        parser.error(f"unknown grid(s) {', '.join(unknown)}; known: {', '.join(GRIDS)}")
    if args.seeds < 1 or args.minutes <= 0 or args.stop_held < 1 or not 0.0 < args.threshold <= 1.0:
        parser.error("--seeds and --stop-held must be >= 1, --minutes > 0 and --threshold a rate in (0, 1]")
    args.stop_at = args.threshold  # bench/ablation.py's name for it
    return args


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    failed = [] if args.summary else learning.run_each(
        (f"{grid} seed {seed}", learning_args(args, variant(args.task, grid), seed)
         + ["--thresholds", f"{args.threshold:g}"])
        for seed in range(args.first_seed, args.first_seed + args.seeds) for grid in args.grids
        if not seed_csv(args, grid, seed).exists())
    if failed is None:
        return 130
    costs = time_updates(args.grids) if args.costs else {}
    print(write_results(args, costs))
    print(f"wrote {Path(args.results_dir) / f'grid_study-{args.task}'}.{{md,csv}}")
    return learning.exit_code(failed)


if __name__ == "__main__":
    sys.exit(main())
