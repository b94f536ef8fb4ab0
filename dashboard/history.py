"""``/api/history``: the run's learning curves, from ``metrics/eval.csv`` and ``metrics/learner.csv``.

Columns are read by name and missing ones are simply absent, so older runs and partial
files still chart. Long series are thinned to at most ``MAX_POINTS`` evenly spaced rows (the
first and last kept); the answer is memoised on the files' stamps (filecache.py).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import yaml

from dashboard.filecache import CsvTail, FileCache, stamp

MAX_POINTS = 500
EVAL_COLUMNS = ("time", "weights_version", "learner_step", "env_steps", "episodes", "success_rate", "mean_return",
                "unreachable_rate")
#: learner.csv columns the page charts: per-depth TD loss and chosen-voxel Q, rates, replay state.
LEARNER_COLUMNS = re.compile(r"^(step|updates_per_s|samples_per_s|weights_version|skipped_updates"
                             r"|loss/depth\d+|q_chosen/depth\d+|replay_[a-z_]+)$")


class RunHistory:
    """Reads one run directory's metric files for the dashboard."""

    def __init__(self, run_dir: Path, cache: FileCache | None = None) -> None:
        self.run_dir = Path(run_dir)
        self.eval_csv = CsvTail(self.run_dir / "metrics" / "eval.csv")
        self.learner_csv = CsvTail(self.run_dir / "metrics" / "learner.csv")
        self.cache = cache or FileCache()

    @property
    def files(self) -> list[Path]:
        return [self.eval_csv.path, self.learner_csv.path, self.run_dir / "config.yaml", self.run_dir / "launched_at"]

    def config(self) -> dict:
        """The run's resolved config.yaml ({} when missing or unreadable)."""
        path = self.run_dir / "config.yaml"

        def load() -> dict:
            try:
                data = yaml.safe_load(path.read_text(encoding="utf-8"))
            except (OSError, yaml.YAMLError):
                return {}
            return data if isinstance(data, dict) else {}

        return self.cache.get(("config", str(path), stamp(path)), load)

    def history(self) -> tuple[dict, str]:
        """(the /api/history body, its ETag)."""
        return self.cache.for_files("history", self.files, self._build)

    def started_at(self) -> float | None:
        try:
            return float((self.run_dir / "launched_at").read_text().strip())
        except (OSError, ValueError):
            return None

    def _build(self) -> dict:
        started = self.started_at()
        header, rows = self.eval_csv.read()
        series = columns(header, rows, EVAL_COLUMNS)
        times = series.get("time", [])
        if started is None and times:
            started = next((t for t in times if t is not None), None)
        if times:
            series["minutes"] = [None if t is None or started is None else round((t - started) / 60.0, 3)
                                 for t in times]
            series["env_steps_per_s"] = env_rates(times, series.get("env_steps", []), started)
        lheader, lrows = self.learner_csv.read()
        learner = columns(lheader, lrows, [h for h in lheader if LEARNER_COLUMNS.match(h)])
        replay = self.config().get("replay") or {}
        capacity = replay.get("capacity_transitions") if isinstance(replay, dict) else None
        return {
            "run_id": (self.config().get("run") or {}).get("run_id", self.run_dir.name),
            "started_at": started,
            "replay_capacity": capacity if isinstance(capacity, (int, float)) else None,
            "eval": {"rows": len(rows), "series": thin(series)},
            "learner": {"rows": len(lrows), "series": thin(learner)},
        }


def columns(header: list[str], rows: list[list[float | None]], wanted) -> dict[str, list[float | None]]:
    """The ``wanted`` columns present in ``header``, as lists (integers where the value is whole)."""
    out: dict[str, list[Any]] = {}
    for name in wanted:
        if name in header:
            i = header.index(name)
            out[name] = [_tidy(r[i]) for r in rows]
    return out


def env_rates(times: list, env_steps: list, started: float | None) -> list[float | None]:
    """Env steps per second between consecutive evaluations (the first: since the run started)."""
    out: list[float | None] = []
    prev_t, prev_s = started, 0.0
    for t, s in zip(times, env_steps):
        rate = None
        if None not in (t, s, prev_t, prev_s) and t > prev_t and s >= prev_s:
            rate = round((s - prev_s) / (t - prev_t), 3)
        out.append(rate)
        if t is not None and s is not None:
            prev_t, prev_s = t, s
    return out


def thin(series: dict[str, list], max_points: int = MAX_POINTS) -> dict[str, list]:
    """Every series cut to at most ``max_points`` evenly spaced rows, first and last kept."""
    n = max((len(v) for v in series.values()), default=0)
    if n <= max_points:
        return series
    keep = sorted({round(i * (n - 1) / (max_points - 1)) for i in range(max_points)})
    return {k: [v[i] for i in keep] for k, v in series.items()}


def _tidy(value: float | None) -> float | int | None:
    """Whole numbers as ints, others to 6 significant digits (a chart needs no more; the JSON stays small)."""
    if value is None or not math.isfinite(value):
        return None
    if value.is_integer() and abs(value) < 2**53:
        return int(value)
    return round(value, 3) if abs(value) >= 1e5 else float(f"{value:.6g}")  # times stay to the millisecond
