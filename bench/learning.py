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
* ``<results-dir>/<task>-<preset>[-<tag>].{csv,png}``: the seeds aggregated by evaluation index
  (see ``aggregate``), plotted against env steps and minutes: seeds thin, mean thick, worst dashed;
* a markdown table, for BENCHMARKS.md, of when each seed (and the worst) first reached each
  ``--thresholds`` success rate; ``--summary`` prints only that.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence

BUDGET_FILE = "bench_budget.json"
CURVE_FIELDS = ["minutes", "env_steps", "learner_step", "weights_version", "success_rate", "episodes"]
OPTIONAL_RATES = ["unreachable_rate"]  # eval.csv columns carried into curves when present
AGGREGATE_FIELDS = ["minutes", "env_steps", "learner_step", "success_rate", "success_mean", "seeds", "carried"]
Curve = list[dict]


# -- budget bookkeeping -------------------------------------------------------------


@dataclass
class Budget:
    """Wall-clock [start, end] segments the bench has given one run, one per bench launch."""

    segments: list[list[float]] = field(default_factory=list)
    #: the success rate the run held when the bench stopped it (``--stop-at``); None while it has not
    held_rate: Optional[float] = None

    @property
    def spent(self) -> float:
        return sum(max(0.0, end - start) for start, end in self.segments)

    def remaining(self, budget_s: float) -> float:
        return max(0.0, budget_s - self.spent)


def load_budget(run_dir: Path) -> Budget:
    """The run's bookkeeping; empty for a run the bench never ran (or launched by hand)."""
    try:
        data = json.loads((run_dir / BUDGET_FILE).read_text())
    except (FileNotFoundError, ValueError):
        return Budget()
    held = data.get("held_rate")
    return Budget([[float(start), float(end)] for start, end in data.get("segments", [])],
                  None if held is None else float(held))


def save_budget(run_dir: Path, budget: Budget) -> None:
    """Write atomically, so a bench killed mid-write leaves the previous bookkeeping intact."""
    tmp = run_dir / (BUDGET_FILE + ".tmp")
    tmp.write_text(json.dumps({"spent_s": round(budget.spent, 3), "segments": budget.segments,
                               "held_rate": budget.held_rate}) + "\n")
    os.replace(tmp, run_dir / BUDGET_FILE)


def active_seconds(t: float, launched_at: float, segments: Sequence[Sequence[float]]) -> float:
    """Seconds the run had been running at wall time t: gaps between bench segments left out.

    Without bookkeeping this is ``t - launched_at``, as the launcher counts; time before the
    first segment (a run launched by hand, then benched) counts in full.
    """
    if not segments:
        return t - launched_at
    total = max(0.0, min(t, segments[0][0]) - launched_at)
    for start, end in segments:
        total += max(0.0, min(t, end) - max(start, launched_at))
    return total + max(0.0, t - segments[-1][1])  # after the last progress write (a killed bench)


# -- reading curves -----------------------------------------------------------------


def _number(row: Mapping[str, Optional[str]], name: str) -> Optional[float]:
    try:
        return float(row.get(name))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None


def _launched_at(run_dir: Path, budget: Budget, rows: Sequence[Mapping[str, Optional[str]]]) -> float:
    """The run's first start: the launcher's record, else the bench's, else the first evaluation."""
    try:
        return float((run_dir / "launched_at").read_text())
    except (FileNotFoundError, ValueError):
        pass
    if budget.segments:
        return budget.segments[0][0]
    times = [t for t in (_number(r, "time") for r in rows) if t is not None]
    return times[0] if times else 0.0


def read_eval(run_dir: Path) -> Curve:
    """The run's evaluations as curve points (minutes since launch, counters, rates).

    Columns are read by name: extra columns are ignored, missing counters read as 0, and a row
    without a time or success rate (a line cut short by a killed writer) is skipped.
    """
    source = run_dir / "metrics" / "eval.csv"
    if not source.exists():
        return []
    with source.open(newline="") as f:
        rows = list(csv.DictReader(f))
    budget = load_budget(run_dir)
    launched_at = _launched_at(run_dir, budget, rows)
    curve: Curve = []
    for row in rows:
        t, success = _number(row, "time"), _number(row, "success_rate")
        if t is None or success is None:
            continue
        point: dict = {"minutes": active_seconds(t, launched_at, budget.segments) / 60}
        for name in ("env_steps", "learner_step", "weights_version"):
            point[name] = int(_number(row, name) or 0)
        point["success_rate"] = success
        point["episodes"] = int(_number(row, "episodes") or 0)
        for name in OPTIONAL_RATES:
            if name in row:
                point[name] = _number(row, name)
        curve.append(point)
    return curve


def read_curve_csv(path: Path) -> Curve:
    """A per-seed curve written by ``write_results`` (numbers back as floats, counters as ints)."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    counters = {"env_steps", "learner_step", "weights_version", "episodes"}
    return [{k: (int(float(v)) if k in counters else float(v)) for k, v in row.items() if v not in ("", None)}
            for row in rows]


def aggregate(curves: Sequence[Curve], held: Sequence[bool] = ()) -> Curve:
    """Seeds combined by evaluation index k: the k-th evaluation of every seed.

    The evaluator scores every few weights versions, so the k-th evaluations of the seeds are
    comparable points in training. ``success_rate`` is the worst seed's success (a curve that
    says "every seed got here"), ``success_mean`` the mean; ``minutes``/``env_steps``/
    ``learner_step`` are the largest across the seeds that ran that far.

    ``held[i]`` says seed i ended because it held its rate (``--stop-at``): past its last
    evaluation it keeps that success to the end of the longest seed, so a fast seed that
    stopped early cannot end the aggregate before a slow seed gets there (``carried`` counts
    such seeds per row). Any other seed that ends ends the aggregate, since nothing is known of
    it afterwards; a seed with no evaluation empties it. ``seeds`` is always the number of curves.
    """
    if not curves or not all(curves):
        return []
    held = list(held) + [False] * (len(curves) - len(held))
    rows: Curve = []
    for k in range(max(len(c) for c in curves)):
        live = [c[k] for c in curves if k < len(c)]
        if any(k >= len(c) and not h for c, h in zip(curves, held)):
            break
        rates = [c[min(k, len(c) - 1)]["success_rate"] for c in curves]
        rows.append({
            "minutes": max(p["minutes"] for p in live),
            "env_steps": max(p["env_steps"] for p in live),
            "learner_step": max(p["learner_step"] for p in live),
            "success_rate": min(rates),
            "success_mean": sum(rates) / len(rates),
            "seeds": len(curves),
            "carried": len(curves) - len(live),
        })
    return rows


def write_csv(path: Path, rows: Curve, fields: Sequence[str]) -> Path:
    """Rows as CSV with exactly these columns (missing ones empty, others dropped)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(fields), restval="", extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    return path


def curve_fields(curve: Curve) -> list[str]:
    """The curve columns, plus the optional rates this run's evaluator recorded."""
    return CURVE_FIELDS + [n for n in OPTIONAL_RATES if any(n in p for p in curve)]


# -- plots and summary --------------------------------------------------------------


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plottable(curve: Curve, x: str) -> Curve:
    """A weights version published before the learner saw a batch carries no env-step count."""
    return [p for p in curve if x != "env_steps" or p["env_steps"] or not p["learner_step"]]


def plot_seeds(curves: Mapping[str, Curve], combined: Curve, out_png: Path, title: str) -> Path:
    """Success vs env steps and vs minutes: one seed plain; several thin, mean thick, worst dashed."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for ax, x, label in zip(axes, ("env_steps", "minutes"), ("environment steps (decisions)", "wall-clock minutes")):
        if len(curves) == 1:
            points = _plottable(next(iter(curves.values())), x)
            ax.plot([p[x] for p in points], [100 * p["success_rate"] for p in points], marker="o")
        else:
            for name, curve in curves.items():
                points = _plottable(curve, x)
                ax.plot([p[x] for p in points], [100 * p["success_rate"] for p in points],
                        lw=0.8, alpha=0.7, label=name)
            points = _plottable(combined, x)
            xs = [p[x] for p in points]
            ax.plot(xs, [100 * p["success_mean"] for p in points], lw=2.5, color="black",
                    label=f"mean of {len(curves)} seeds")
            ax.plot(xs, [100 * p["success_rate"] for p in points], lw=1.5, ls="--", color="tab:red",
                    label="worst seed")
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    counts = sorted({p["episodes"] for curve in curves.values() for p in curve})
    axes[0].set_ylabel(f"greedy eval success (%), {'/'.join(map(str, counts))} episodes per point")
    axes[0].set_ylim(-2, 102)
    if len(curves) > 1:
        axes[1].legend(fontsize="small", loc="lower right")
    fig.suptitle(title)
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


def plot(run_dir: Path) -> Optional[Path]:
    """Write runs/<id>/learning_curve.csv/.png from the evaluator's eval.csv; returns the PNG path."""
    curve = read_eval(run_dir)
    if not curve:
        print(f"no evaluations recorded in {run_dir / 'metrics' / 'eval.csv'}")
        return None
    write_csv(run_dir / "learning_curve.csv", curve, curve_fields(curve))
    out_png = plot_seeds({run_dir.name: curve}, curve, run_dir / "learning_curve.png", run_dir.name)
    for p in curve:
        print(f"{p['minutes']:7.1f} min  {p['env_steps']:7d} env steps  learner step {p['learner_step']:6d}  "
              f"success {100 * p['success_rate']:5.1f}%")
    return out_png


def first_reaching(curve: Curve, threshold: float, key: str = "success_rate") -> Optional[dict]:
    """The first evaluation at or above threshold (even if success drops again later)."""
    return next((p for p in curve if p[key] >= threshold), None)


def _reached(point: Optional[dict]) -> str:
    if point is None:
        return "not reached"
    return f"{point['minutes']:.1f} min, {point['env_steps']} env steps, step {point['learner_step']}"


def summarise(curves: Mapping[str, Curve], combined: Curve, thresholds: Sequence[float]) -> str:
    """A markdown table: when each seed (and the worst, and the mean) first reached each threshold."""
    header = ["run", "evals"] + [f"success ≥ {100 * t:g} %" for t in thresholds] + ["final success"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]

    def row(name: str, curve: Curve, key: str) -> None:
        final = f"{100 * curve[-1][key]:.0f} %" if curve else "-"
        cells = [name, str(len(curve))] + [_reached(first_reaching(curve, t, key)) for t in thresholds] + [final]
        lines.append("| " + " | ".join(cells) + " |")

    for name, curve in curves.items():
        row(name, curve, "success_rate")
    if len(curves) > 1:
        row("worst seed (per eval)", combined, "success_rate")
        row("mean of seeds", combined, "success_mean")
    return "\n".join(lines)


# -- running ------------------------------------------------------------------------


def stop(proc: subprocess.Popen) -> None:
    """SIGTERM the launcher's process group (it stops every role within 10 s), then insist.

    SIGTERM, not SIGINT: a bench started in the background (``nohup ... &``) inherits an
    ignored SIGINT, and then nothing would stop.
    """
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)
    except ProcessLookupError:
        pass
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def held(curve: Curve, threshold: float, times: int) -> bool:
    """True when the last ``times`` evaluations all reached ``threshold`` (a run that can stop)."""
    return times > 0 and len(curve) >= times and all(p["success_rate"] >= threshold for p in curve[-times:])


def run_budgeted(cmd: Sequence[str], run_dir: Path, budget_s: float, progress_every: float = 30.0,
                 done: Optional[Callable[[], bool]] = None) -> Optional[int]:
    """Run cmd until the run has had budget_s seconds over all bench launches, or ``done()``.

    Returns the exit code if it ended by itself, None if the bench stopped it (or had no time
    left). The spent time is saved every progress_every seconds and on the way out, Ctrl-C
    included, so a rerun picks up where this one stopped.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    budget = load_budget(run_dir)
    if budget.remaining(budget_s) <= 0:
        return None
    now = time.time()
    budget.segments.append([now, now])
    save_budget(run_dir, budget)
    code: Optional[int] = None
    proc = subprocess.Popen(list(cmd), start_new_session=True)
    try:
        while code is None and budget.remaining(budget_s) > 0:
            try:
                code = proc.wait(timeout=min(progress_every, budget.remaining(budget_s)))
            except subprocess.TimeoutExpired:
                pass
            budget.segments[-1][1] = time.time()
            save_budget(run_dir, budget)
            if code is None and done is not None and done():
                break
    finally:
        budget.segments[-1][1] = time.time()
        save_budget(run_dir, budget)
        if code is None:
            stop(proc)
            budget.segments[-1][1] = time.time()  # shutdown counts too: the run held the machine
            save_budget(run_dir, budget)
    return code


#: A bounded busy loop: spins until its deadline (seconds since the epoch), then exits by itself.
HOG = "import sys, time\nend = float(sys.argv[1])\nwhile time.time() < end:\n    pass\n"


@contextlib.contextmanager
def cpu_hog(cores: int, seconds: float):
    """Keep ``cores`` cores busy for at most ``seconds`` (the busy-machine condition), then stop."""
    deadline = time.time() + seconds + 120  # a hog left behind by a killed bench still ends by itself
    hogs = [subprocess.Popen([sys.executable, "-c", HOG, str(deadline)]) for _ in range(cores)]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


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
        code = run_budgeted(cmd, run_dir, budget_s, progress_every=15.0 if args.stop_at is not None else 30.0,
                            done=done)
    if code is not None:
        print(f"{run_id}: launcher exited by itself with code {code}", flush=True)
    elif done():
        mark_held(run_dir, args.stop_at)
    plot(run_dir)
    return not code


def mark_held(run_dir: Path, rate: float) -> None:
    """Record that the bench stopped this run because it held ``rate``: its curve is then complete."""
    budget = load_budget(run_dir)
    budget.held_rate = rate
    save_budget(run_dir, budget)


def _interrupt(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt  # SIGTERM too: stop the run and save the budget on the way out


def results_stem(args: argparse.Namespace) -> str:
    return f"{args.task}-{args.preset}" + (f"-{args.tag}" if args.tag else "")


def seed_run_ids(args: argparse.Namespace) -> dict[int, str]:
    """Run ids of the seeds in range: fixed names, so rerunning the command resumes them."""
    prefix = args.prefix or f"learn-{args.task}-{args.preset}" + (f"-{args.tag}" if args.tag else "")
    return {seed: f"{prefix}-s{seed}" for seed in range(args.first_seed, args.first_seed + args.seeds)}


def load_seeds(args: argparse.Namespace) -> dict[int, Curve]:
    """Curves of the seeds in range that have evaluations; the others are named and left out."""
    curves: dict[int, Curve] = {}
    for seed, run_id in seed_run_ids(args).items():
        curve = read_eval(Path(args.runs_dir) / run_id)
        if curve:
            curves[seed] = curve
        else:
            print(f"{run_id}: no evaluations, left out of the aggregate")
    return curves


def held_seeds(args: argparse.Namespace, seeds) -> list[bool]:
    """Per seed, whether the bench stopped its run because it held its rate (see ``aggregate``)."""
    run_ids = seed_run_ids(args)
    return [load_budget(Path(args.runs_dir) / run_ids[seed]).held_rate is not None for seed in seeds]


def combine(args: argparse.Namespace, curves: Mapping[int, Curve]) -> Curve:
    """The seeds' aggregate, seeds stopped by ``--stop-at`` holding their rate to the end."""
    return aggregate(list(curves.values()), held_seeds(args, curves))


def write_results(args: argparse.Namespace, curves: Mapping[int, Curve], combined: Curve) -> None:
    """Per-seed CSVs, the aggregate CSV and the PNG under the results dir."""
    results, stem = Path(args.results_dir), results_stem(args)
    for seed, curve in curves.items():
        write_csv(results / f"{stem}-s{seed}.csv", curve, curve_fields(curve))
    write_csv(results / f"{stem}.csv", combined, AGGREGATE_FIELDS)
    named = {f"seed {seed}": curve for seed, curve in curves.items()}
    png = plot_seeds(named, combined, results / f"{stem}.png", f"{stem}, {len(curves)} seed(s)")
    print(f"wrote {results / stem}.csv, {png} and {len(curves)} per-seed CSV(s)")


def add_stop_arguments(parser: argparse.ArgumentParser) -> None:
    """``--stop-at`` / ``--stop-held``: shared with bench/ablation.py, which passes them on."""
    parser.add_argument("--stop-at", type=float, default=None, metavar="RATE",
                        help="stop a run early once its last --stop-held evaluations reached this success rate")
    parser.add_argument("--stop-held", type=int, default=3, metavar="N", help="evaluations --stop-at must hold")


def check_stop_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """One line, before anything runs, for a rate outside (0, 1] or a hold under 1."""
    if args.stop_at is not None and not (0.0 < args.stop_at <= 1.0 and args.stop_held >= 1):
        parser.error("--stop-at must be a success rate in (0, 1] and --stop-held >= 1")


def parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="reach_target", help="task to learn")
    parser.add_argument("--minutes", type=float, default=60.0, help="wall-clock budget per seed")
    parser.add_argument("--preset", default="cpu-small", help="config preset in configs/")
    parser.add_argument("--seeds", type=int, default=1, help="number of seeded runs, one after another")
    parser.add_argument("--first-seed", type=int, default=1, help="seed of the first run")
    parser.add_argument("--tag", default=None, help="names an ablation variant in run ids and result files")
    parser.add_argument("--prefix", default=None, help="run id prefix (default: learn-<task>-<preset>[-<tag>])")
    parser.add_argument("--run-id", default=None, help="one run with exactly this id (no seeds, no aggregate)")
    parser.add_argument("--runs-dir", default="runs", help="where runs live")
    parser.add_argument("--results-dir", default="bench/results", help="where aggregate curves go")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override, every seed")
    parser.add_argument("--thresholds", type=float, nargs="+", default=[0.8, 0.9], help="success rates to time")
    parser.add_argument("--cpu-hog", type=int, default=0, metavar="CORES",
                        help="keep this many cores busy during each run (robustness to a shared machine)")
    add_stop_arguments(parser)
    parser.add_argument("--plot-only", action="store_true", help="only re-aggregate and re-plot existing runs")
    parser.add_argument("--summary", action="store_true", help="only print the threshold table")
    args = parser.parse_args(argv)
    check_stop_arguments(parser, args)
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
