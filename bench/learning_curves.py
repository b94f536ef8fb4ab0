"""Learning curves: a run's greedy evaluations as points, seeds combined, plots and the markdown table.

A curve is a list of points (dicts), one per evaluation: ``minutes`` of the run's bench time,
``env_steps``, ``learner_step``, ``weights_version``, ``success_rate``, ``episodes`` and the
optional rates the evaluator recorded. Per-seed curves are written as CSV and read back, so
seeds run on other days still combine.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Mapping, Optional, Sequence

from run_budget import Budget, active_seconds, load_budget

CURVE_FIELDS = ["minutes", "env_steps", "learner_step", "weights_version", "success_rate", "episodes"]
OPTIONAL_RATES = ["unreachable_rate"]  # eval.csv columns carried into curves when present
AGGREGATE_FIELDS = ["minutes", "env_steps", "learner_step", "success_rate", "success_mean", "seeds", "carried"]
Curve = list[dict]


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


def held(curve: Curve, threshold: float, times: int) -> bool:
    """True when ``times`` evaluations in a row reached ``threshold`` anywhere in the curve (a run that can stop).

    Anywhere, not only at the end: a fast learner evaluates every ~12 s, so by the time the bench
    looks again the pair that held may already be followed by an evaluation below it.
    """
    run = 0
    for point in curve:
        run = run + 1 if point["success_rate"] >= threshold else 0
        if times > 0 and run >= times:
            return True
    return False


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plottable(curve: Curve, x: str) -> Curve:
    """A weights version published before the learner saw a batch carries no env-step count."""
    return [p for p in curve if x != "env_steps" or p["env_steps"] or not p["learner_step"]]


def plot_seeds(curves: Mapping[str, Curve], combined: Curve, out_png: Path, title: str) -> Path:
    """Success vs env steps and vs minutes: one seed plain; several thin, mean thick, worst dashed."""
    plt = pyplot()
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


def when_reached(point: Optional[dict]) -> str:
    if point is None:
        return "not reached"
    return f"{point['minutes']:.1f} min, {point['env_steps']} env steps, step {point['learner_step']}"


def summarise(curves: Mapping[str, Curve], combined: Curve, thresholds: Sequence[float]) -> str:
    """A markdown table: when each seed (and the worst, and the mean) first reached each threshold."""
    header = ["run", "evals"] + [f"success ≥ {100 * t:g} %" for t in thresholds] + ["final success"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]

    def row(name: str, curve: Curve, key: str) -> None:
        final = f"{100 * curve[-1][key]:.0f} %" if curve else "-"
        cells = [name, str(len(curve))] + [when_reached(first_reaching(curve, t, key)) for t in thresholds] + [final]
        lines.append("| " + " | ".join(cells) + " |")

    for name, curve in curves.items():
        row(name, curve, "success_rate")
    if len(curves) > 1:
        row("worst seed (per eval)", combined, "success_rate")
        row("mean of seeds", combined, "success_mean")
    return "\n".join(lines)
