"""Learning curves: train C2F-ARM on a task under a wall-clock budget, over seeds, and plot eval success.

    python bench/learning.py --task reach_target --minutes 60                 # one run, seed 1
    python bench/learning.py --task reach_target --minutes 60 --seeds 3       # seeds 1..3, one after another
    python bench/learning.py --task reach_target --minutes 60 --seeds 3 \\
        --tag demo25 --set replay.demo_fraction=0.25                          # an ablation variant
    python bench/learning.py --task reach_target --seeds 3 --plot-only        # re-aggregate, run nothing
    python bench/learning.py --task reach_target --seeds 3 --summary --thresholds 0.8 0.9
    python bench/learning.py --run-id learn-reach-1 --minutes 22              # one named run (no seed suffix)

Each seed runs the whole distributed system (``c2farm launch``) as it would run for a user, as
run ``<prefix>-s<seed>`` with ``--set run.seed=<seed>`` (prefix: ``learn-<task>-<preset>[-<tag>]``,
or ``--prefix``); extra ``--set`` items go to every seed. Seeds run one after the other, since a
small machine has few cores to share. The bench stops a run (SIGINT to its process group) once
it has had ``--minutes`` of wall-clock time in all, or, with ``--stop-at RATE``, once its last
``--stop-held`` evaluations all reached RATE (an ablation times the thresholds and needs no more).

Rerunning the same command resumes rather than restarts: the launcher resumes an existing run
id, and ``runs/<id>/bench_budget.json`` records the wall-clock segments the bench has given that
run (written every 30 s, so a killed bench loses at most that much), so a rerun only spends what
is left of the budget and skips seeds whose budget is used up. Curve minutes count only those
segments, so a run resumed the next day is not stretched by the time it lay idle.

Outputs, from each run's ``runs/<id>/metrics/eval.csv`` (columns read by name):

* ``runs/<id>/learning_curve.{csv,png}`` after each run, as before;
* ``<results-dir>/<task>-<preset>[-<tag>]-s<seed>.csv``: each seed's curve;
  ``...-s<seed>.machine.json`` beside it: the CPU (model, cores, speed flags), commit and torch it ran with;
* ``<results-dir>/<task>-<preset>[-<tag>].{csv,png}``: the seeds aggregated by evaluation index
  (see ``aggregate``), plotted against env steps and minutes: seeds thin, mean thick, worst dashed;
* a markdown table, for BENCHMARKS.md, of when each seed (and the worst) first reached each
  ``--thresholds`` success rate; ``--summary`` prints only that.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Iterable, Mapping, Optional, Sequence

from learning_curves import (
    AGGREGATE_FIELDS,
    Curve,
    aggregate,
    curve_fields,
    held,
    plot,
    plot_seeds,
    read_curve_csv,
    read_eval,
    summarise,
    write_csv,
)
from run_budget import cpu_hog, load_budget, mark_held, run_budgeted


def launch_command(args: argparse.Namespace, run_id: str, seed: Optional[int]) -> list[str]:
    """``c2farm launch`` for one run; the user's ``--set`` items come last, so they win."""
    cmd = [sys.executable, "-m", "deploy.cli", "launch", "--preset", args.preset, "--task", args.task,
           "--run-id", run_id, "--set", f"run.runs_dir={args.runs_dir}"]
    if seed is not None:
        cmd += ["--set", f"run.seed={seed}"]
    for item in args.set:
        cmd += ["--set", item]
    return cmd


def train(args: argparse.Namespace, run_id: str, seed: Optional[int]) -> bool:
    """One run's (remaining) budget, then its own learning curve; False if the launcher failed."""
    run_dir = Path(args.runs_dir) / run_id
    budget_s = args.minutes * 60

    def done() -> bool:
        return args.stop_at is not None and held(read_eval(run_dir), args.stop_at, args.stop_held)

    if done():
        mark_held(run_dir, args.stop_at)
        print(f"{run_id}: held {100 * args.stop_at:g} % on its last {args.stop_held} evaluations, skipping", flush=True)
        return True
    left = load_budget(run_dir).remaining(budget_s)
    if left <= 0:
        print(f"{run_id}: budget of {args.minutes:g} min already spent, skipping", flush=True)
        return True
    cmd = launch_command(args, run_id, seed)
    hog = f", {args.cpu_hog} core(s) kept busy beside it" if args.cpu_hog else ""
    print(f"{run_id}: {left / 60:.1f} of {args.minutes:g} min left{hog}\n+ {' '.join(cmd)}", flush=True)
    with cpu_hog(args.cpu_hog, left):
        code = run_budgeted(cmd, run_dir, budget_s, progress_every=5.0 if args.stop_at is not None else 30.0,
                            done=done)
    if code is not None:
        print(f"{run_id}: launcher exited by itself with code {code}", flush=True)
    elif done():
        mark_held(run_dir, args.stop_at)
    plot(run_dir)
    return not code


def _interrupt(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt  # SIGTERM too: stop the run and save the budget on the way out


def results_stem(args: argparse.Namespace) -> str:
    return f"{args.task}-{args.preset}" + (f"-{args.tag}" if args.tag else "")


def seed_run_id(args: argparse.Namespace, seed: int) -> str:
    """A seed's run id: a fixed name, so rerunning the command resumes it."""
    return f"{args.prefix or 'learn-' + results_stem(args)}-s{seed}"


def seed_run_ids(args: argparse.Namespace) -> dict[int, str]:
    """Run ids of the seeds in range."""
    return {seed: seed_run_id(args, seed) for seed in range(args.first_seed, args.first_seed + args.seeds)}


def load_seeds(args: argparse.Namespace) -> dict[int, Curve]:
    """Curves of the seeds in range: each run's evaluations, else the seed's CSV in the results dir.

    The CSV is the record (committed); a run directory is one machine's scratch, gone on the next.
    Seeds with neither are named and left out.
    """
    curves: dict[int, Curve] = {}
    for seed, run_id in seed_run_ids(args).items():
        recorded = Path(args.results_dir) / f"{results_stem(args)}-s{seed}.csv"
        curve = read_eval(Path(args.runs_dir) / run_id) or (read_curve_csv(recorded) if recorded.exists() else [])
        if curve:
            curves[seed] = curve
        else:
            print(f"{run_id}: no evaluations and no {recorded.name}, left out of the aggregate")
    return curves


def held_seeds(args: argparse.Namespace, curves: Mapping[int, Curve]) -> list[bool]:
    """Per seed, whether the bench stopped its run because it held its rate (see ``aggregate``).

    The run's budget file says so; a seed read back from its CSV (its run directory gone) held if
    its curve holds ``--stop-at`` as the stopping rule reads it.
    """
    flags = []
    for seed, curve in curves.items():  # seeds out of range too: an ablation combines every recorded one
        run_dir = Path(args.runs_dir) / seed_run_id(args, seed)
        if run_dir.is_dir():
            flags.append(load_budget(run_dir).held_rate is not None)
        else:
            flags.append(args.stop_at is not None and held(curve, args.stop_at, args.stop_held))
    return flags


def combine(args: argparse.Namespace, curves: Mapping[int, Curve]) -> Curve:
    """The seeds' aggregate, seeds stopped by ``--stop-at`` holding their rate to the end."""
    return aggregate(list(curves.values()), held_seeds(args, curves))


def write_results(args: argparse.Namespace, curves: Mapping[int, Curve], combined: Curve) -> None:
    """Per-seed CSVs, the aggregate CSV and the PNG under the results dir."""
    results, stem = Path(args.results_dir), results_stem(args)
    for seed, curve in curves.items():
        write_csv(results / f"{stem}-s{seed}.csv", curve, curve_fields(curve))
        record_machine(Path(args.runs_dir) / seed_run_id(args, seed), machine_record(results / f"{stem}-s{seed}.csv"))
    write_csv(results / f"{stem}.csv", combined, AGGREGATE_FIELDS)
    named = {f"seed {seed}": curve for seed, curve in curves.items()}
    png = plot_seeds(named, combined, results / f"{stem}.png", f"{stem}, {len(curves)} seed(s)")
    print(f"wrote {results / stem}.csv, {png} and {len(curves)} per-seed CSV(s)")


#: What a seed's machine record keeps of its run's versions.json: minutes and updates/s differ several-fold
#: between hosts of one kind (an AVX2-only "AMD EPYC" VM against an AVX-512-bf16 one), so a curve's minutes are read
#: beside the CPU they ran on.
MACHINE_FIELDS = ("cpu", "git_commit", "torch")


def machine_record(seed_csv: Path) -> Path:
    """Where a seed's machine record lies: beside its curve, ``<...>-s<seed>.machine.json``."""
    return seed_csv.with_suffix(".machine.json")


def record_machine(run_dir: Path, out: Path) -> None:
    """``out`` (JSON): the CPU, commit and torch a seed's run last ran with, from its ``versions.json``.

    Left as it is when the run directory is gone (a seed read back from its CSV keeps its record).
    """
    try:
        versions = json.loads((run_dir / "versions.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    out.write_text(json.dumps({k: versions.get(k) for k in MACHINE_FIELDS}, indent=2) + "\n", encoding="utf-8")


def add_stop_arguments(parser: argparse.ArgumentParser) -> None:
    """``--stop-at`` / ``--stop-held``: shared with bench/ablation.py, which passes them on."""
    parser.add_argument("--stop-at", type=float, default=None, metavar="RATE",
                        help="stop a run early once its last --stop-held evaluations reached this success rate")
    parser.add_argument("--stop-held", type=int, default=3, metavar="N", help="evaluations --stop-at must hold")


def check_stop_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """One line, before anything runs, for a rate outside (0, 1] or a hold under 1."""
    if args.stop_at is not None and not (0.0 < args.stop_at <= 1.0 and args.stop_held >= 1):
        parser.error("--stop-at must be a success rate in (0, 1] and --stop-held >= 1")


def run_id_error(args: argparse.Namespace) -> Optional[str]:
    """The first of the seeds' run ids that the launcher would refuse (ids name keys and directories: 1-64
    letters, digits, '_', '.', '-'), as one line; None when every one is valid. Checked before any run starts."""
    from protocol.keys import MAX_ID_LENGTH, is_valid_id

    bad = [run_id for run_id in seed_run_ids(args).values() if not is_valid_id(run_id)]
    if not bad:
        return None
    return (f"run id {bad[0]!r} ({len(bad[0])} characters) is not a valid id: at most {MAX_ID_LENGTH} letters, "
            "digits, '_', '.', '-'; shorten the tag")


def run_each(runs: Iterable[tuple[str, Sequence[str]]]) -> Optional[list[str]]:
    """Run this script once per (name, arguments), in turn, as ablation, ladder and grid study do.

    Returns the names of the runs whose launcher failed, or None once one was interrupted (after
    saying so: rerunning the same command resumes from there).
    """
    script = Path(__file__).resolve()
    failed = []
    for name, argv in runs:
        code = subprocess.run([sys.executable, str(script), *argv]).returncode
        if code == 130:
            print("interrupted; rerun the same command to resume", flush=True)
            return None
        if code:
            failed.append(name)
    return failed


def exit_code(failed: Sequence[str]) -> int:
    """Name the runs whose launcher failed (if any) as the last line; 1 if there were any, else 0."""
    if failed:
        print(f"runs that failed: {', '.join(failed)}")
    return 1 if failed else 0


def add_seed_arguments(parser: argparse.ArgumentParser, seeds: int, each: str) -> None:
    """--preset, --seeds and --first-seed, as every learning bench takes them (``each``: what a seed range is per)."""
    parser.add_argument("--preset", default="cpu-small", help="config preset in configs/")
    parser.add_argument("--seeds", type=int, default=seeds, help=f"seeds {each}, one run after another")
    parser.add_argument("--first-seed", type=int, default=1, help=f"seed of the first run {each}")


def add_place_arguments(parser: argparse.ArgumentParser) -> None:
    """--set, --runs-dir and --results-dir, as every learning bench (learning, ablation, ladder) takes them."""
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override, every run")
    parser.add_argument("--runs-dir", default="runs", help="where runs live")
    parser.add_argument("--results-dir", default="bench/results", help="where curves and tables go")


def parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="reach_target", help="task to learn")
    parser.add_argument("--minutes", type=float, default=60.0, help="wall-clock budget per seed")
    add_seed_arguments(parser, 1, "in all")
    parser.add_argument("--tag", default=None, help="names an ablation variant in run ids and result files")
    parser.add_argument("--prefix", default=None, help="run id prefix (default: learn-<task>-<preset>[-<tag>])")
    parser.add_argument("--run-id", default=None, help="one run with exactly this id (no seeds, no aggregate)")
    add_place_arguments(parser)
    parser.add_argument("--thresholds", type=float, nargs="+", default=[0.8, 0.9], help="success rates to time")
    parser.add_argument("--cpu-hog", type=int, default=0, metavar="CORES",
                        help="keep this many cores busy during each run (robustness to a shared machine)")
    add_stop_arguments(parser)
    parser.add_argument("--plot-only", action="store_true", help="only re-aggregate and re-plot existing runs")
    parser.add_argument("--summary", action="store_true", help="only print the threshold table")
    args = parser.parse_args(argv)
    check_stop_arguments(parser, args)
    if error := run_id_error(args):
        parser.error(error)
    return args


def single_run(args: argparse.Namespace, running: bool) -> int:
    """The ``--run-id`` form: one run as named, its own curve and summary, nothing aggregated."""
    run_dir = Path(args.runs_dir) / args.run_id
    ok = train(args, args.run_id, None) if running else True
    if args.plot_only:
        plot(run_dir)
    curve = read_eval(run_dir)
    if curve:
        print(summarise({args.run_id: curve}, curve, args.thresholds))
    return 0 if ok and curve else 1


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    running = not (args.plot_only or args.summary)
    ok = True
    previous = signal.signal(signal.SIGTERM, _interrupt) if running else None
    try:
        if args.run_id:
            return single_run(args, running)
        if running:
            for seed, run_id in seed_run_ids(args).items():
                ok = train(args, run_id, seed) and ok
    except KeyboardInterrupt:
        print("interrupted; rerun the same command to resume", flush=True)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    curves = load_seeds(args)
    if not curves:
        print("no runs with evaluations found")
        return 1
    combined = combine(args, curves)
    if not args.summary:
        write_results(args, curves, combined)
    print(summarise({f"seed {s}": c for s, c in curves.items()}, combined, args.thresholds))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
