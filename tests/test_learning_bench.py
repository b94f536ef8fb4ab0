"""bench/learning.py without a simulator: fake run dirs in, curves, aggregates, budgets and plots out."""

from __future__ import annotations

import csv
import importlib.util
import json
import sys
from pathlib import Path

import learning_curves  # bench/learning_curves.py
import pytest
import run_budget  # bench/run_budget.py

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("bench_learning", REPO / "bench" / "learning.py")
learning = importlib.util.module_from_spec(_spec)
sys.modules["bench_learning"] = learning  # dataclasses look their module up here
_spec.loader.exec_module(learning)

LAUNCHED = 1_000_000.0
FIELDS = ["time", "weights_version", "learner_step", "env_steps", "episodes", "success_rate", "mean_return"]


def make_run(runs_dir: Path, run_id: str, successes: list[float], minutes_apart: float = 2.0,
             fields: list[str] = FIELDS, extra: dict | None = None) -> Path:
    """A run dir as the launcher and evaluator leave it: launched_at and metrics/eval.csv."""
    run_dir = runs_dir / run_id
    (run_dir / "metrics").mkdir(parents=True)
    (run_dir / "launched_at").write_text(f"{LAUNCHED:.3f}\n")
    with (run_dir / "metrics" / "eval.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        for k, success in enumerate(successes):
            writer.writerow({
                "time": LAUNCHED + 60 * minutes_apart * (k + 1), "weights_version": 1 + 5 * k,
                "learner_step": 50 * k, "env_steps": 300 * k, "episodes": 10, "success_rate": success,
                "mean_return": success, **(extra or {}),
            })
    return run_dir


def point(minutes: float, env_steps: int, learner_step: int, success: float) -> dict:
    return {"minutes": minutes, "env_steps": env_steps, "learner_step": learner_step,
            "weights_version": 1, "success_rate": success, "episodes": 10}


def test_read_eval_reads_columns_by_name(tmp_path: Path) -> None:
    fields = ["success_rate", "time", "env_steps", "episodes", "unreachable_rate", "new_column"]
    run_dir = make_run(tmp_path, "r", [0.0, 0.5], fields=fields, extra={"unreachable_rate": 0.1, "new_column": "x"})
    with (run_dir / "metrics" / "eval.csv").open("a") as f:
        f.write("0.9,")  # a row cut short by a killed writer
    curve = learning_curves.read_eval(run_dir)
    assert [p["success_rate"] for p in curve] == [0.0, 0.5]
    assert [p["minutes"] for p in curve] == pytest.approx([2.0, 4.0])
    assert [p["env_steps"] for p in curve] == [0, 300]
    assert curve[1]["learner_step"] == 0 and curve[1]["weights_version"] == 0  # missing columns read as 0
    assert curve[1]["unreachable_rate"] == pytest.approx(0.1)
    assert learning_curves.curve_fields(curve) == learning_curves.CURVE_FIELDS + ["unreachable_rate"]
    assert learning_curves.read_eval(tmp_path / "absent") == []


def test_aggregate_takes_worst_mean_and_largest() -> None:
    a = [point(1.0, 0, 0, 0.0), point(3.0, 400, 50, 0.6)]
    b = [point(1.5, 0, 0, 0.2), point(2.5, 500, 40, 1.0)]
    rows = learning_curves.aggregate([a, b])
    assert [r["success_rate"] for r in rows] == [0.0, 0.6]
    assert [r["success_mean"] for r in rows] == pytest.approx([0.1, 0.8])
    assert [(r["minutes"], r["env_steps"], r["learner_step"]) for r in rows] == [(1.5, 0, 0), (3.0, 500, 50)]
    assert [r["seeds"] for r in rows] == [2, 2]
    assert list(rows[0]) == learning_curves.AGGREGATE_FIELDS


def test_aggregate_aligns_by_evaluation_index_and_stops_at_shortest_seed() -> None:
    long = [point(k, 100 * k, 10 * k, 0.1 * k) for k in range(5)]
    short = [point(k + 0.5, 90 * k, 9 * k, 0.2 * k) for k in range(3)]
    rows = learning_curves.aggregate([long, short])
    assert len(rows) == 3
    assert rows[2]["success_rate"] == pytest.approx(0.2) and rows[2]["success_mean"] == pytest.approx(0.3)
    assert rows[2]["minutes"] == 2.5 and rows[2]["env_steps"] == 200
    assert learning_curves.aggregate([long, []]) == [] and learning_curves.aggregate([]) == []


def test_a_seed_stopped_because_it_held_its_rate_keeps_it_to_the_end_of_the_longest_seed() -> None:
    slow = [point(2 * k, 100 * k, 50 * k, r) for k, r in enumerate((0.0, 0.3, 0.6, 0.85, 0.9, 0.95))]
    fast = [point(2 * k + 1, 90 * k, 50 * k, r) for k, r in enumerate((0.0, 0.9, 0.95))]  # stopped at 95 %
    rows = learning_curves.aggregate([slow, fast], held=[False, True])
    assert len(rows) == len(slow)  # not cut where the fast seed stopped
    assert [r["success_rate"] for r in rows] == [0.0, 0.3, 0.6, 0.85, 0.9, 0.95]  # the slow seed is the worst
    assert [r["carried"] for r in rows] == [0, 0, 0, 1, 1, 1]
    assert rows[-1]["success_mean"] == pytest.approx(0.95) and rows[-1]["minutes"] == 10
    assert learning_curves.first_reaching(rows, 0.9)["minutes"] == 8  # when every seed had got there
    # A seed that ended for any other reason (budget, crash) still ends the aggregate.
    assert len(learning_curves.aggregate([slow, fast], held=[False, False])) == len(fast)


def test_summary_times_each_threshold_per_seed_and_worst() -> None:
    a = [point(1.0, 0, 0, 0.0), point(5.0, 400, 50, 0.8), point(9.0, 800, 100, 0.7)]
    b = [point(2.0, 0, 0, 0.1), point(6.0, 450, 55, 0.9), point(10.0, 850, 105, 1.0)]
    combined = learning_curves.aggregate([a, b])
    assert learning_curves.first_reaching(a, 0.8) is a[1]  # first, though success drops afterwards
    assert learning_curves.first_reaching(a, 0.9) is None
    table = learning_curves.summarise({"seed 1": a, "seed 2": b}, combined, [0.8, 0.9])
    lines = table.splitlines()
    assert lines[0] == "| run | evals | success ≥ 80 % | success ≥ 90 % | final success |"
    assert lines[2] == "| seed 1 | 3 | 5.0 min, 400 env steps, step 50 | not reached | 70 % |"
    assert lines[3] == "| seed 2 | 3 | 6.0 min, 450 env steps, step 55 | 6.0 min, 450 env steps, step 55 | 100 % |"
    assert lines[4] == "| worst seed (per eval) | 3 | 6.0 min, 450 env steps, step 55 | not reached | 70 % |"
    assert lines[5].startswith("| mean of seeds | 3 | 6.0 min")


def test_budget_bookkeeping_gives_the_remaining_time(tmp_path: Path) -> None:
    budget = run_budget.Budget([[100.0, 400.0], [1000.0, 1500.0]])
    assert budget.spent == 800.0
    assert budget.remaining(3600) == 2800.0 and budget.remaining(600) == 0.0
    run_budget.save_budget(tmp_path, budget)
    assert json.loads((tmp_path / run_budget.BUDGET_FILE).read_text())["spent_s"] == 800.0
    assert run_budget.load_budget(tmp_path).segments == budget.segments
    assert run_budget.load_budget(tmp_path / "absent").spent == 0.0
    # Curve time leaves out the gap between a killed bench and its rerun.
    assert run_budget.active_seconds(300.0, 110.0, budget.segments) == 190.0
    assert run_budget.active_seconds(1200.0, 110.0, budget.segments) == 290.0 + 200.0
    assert run_budget.active_seconds(1600.0, 110.0, budget.segments) == 290.0 + 500.0 + 100.0
    assert run_budget.active_seconds(300.0, 110.0, []) == 190.0


def test_run_budgeted_stops_at_budget_and_a_rerun_spends_only_the_rest(tmp_path: Path) -> None:
    sleeper = [sys.executable, "-c", "import time; time.sleep(30)"]
    assert run_budget.run_budgeted(sleeper, tmp_path, budget_s=0.5, progress_every=0.2) is None
    spent = run_budget.load_budget(tmp_path).spent
    assert 0.5 <= spent < 5.0
    assert run_budget.run_budgeted(sleeper, tmp_path, budget_s=0.5) is None  # used up: nothing launched
    assert len(run_budget.load_budget(tmp_path).segments) == 1
    quitter = [sys.executable, "-c", "raise SystemExit(3)"]
    assert run_budget.run_budgeted(quitter, tmp_path / "other", budget_s=30) == 3


def test_a_run_stops_once_it_has_held_the_rate_and_a_rerun_does_not_restart_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert learning_curves.held([{"success_rate": r} for r in (0.2, 0.9, 0.95)], 0.9, 2)
    assert not learning_curves.held([{"success_rate": r} for r in (0.9, 0.5, 0.95)], 0.9, 2)
    # a pair that held is held even when the bench looks only after a lower evaluation followed it
    assert learning_curves.held([{"success_rate": r} for r in (0.8, 0.8, 0.75)], 0.8, 2)
    sleeper = [sys.executable, "-c", "import time; time.sleep(30)"]
    checks = iter([False, True])
    stopped = run_budget.run_budgeted(sleeper, tmp_path, budget_s=60, progress_every=0.2, done=lambda: next(checks))
    assert stopped is None
    assert run_budget.load_budget(tmp_path).spent < 10  # stopped on done(), long before the budget

    runs = tmp_path / "runs"
    make_run(runs, "learn-push_button-cpu-small-s1", [0.0, 0.9, 1.0])  # held 90 % twice, budget left

    def no_launch(*_args, **_kwargs):
        raise AssertionError("relaunched a run that had already held its rate")

    monkeypatch.setattr(learning, "run_budgeted", no_launch)
    argv = ["--task", "push_button", "--minutes", "10", "--stop-at", "0.9", "--stop-held", "2",
            "--runs-dir", str(runs), "--results-dir", str(tmp_path / "res")]
    assert learning.main(argv) == 0
    assert run_budget.load_budget(runs / "learn-push_button-cpu-small-s1").held_rate == 0.9  # its curve is complete


def test_cli_skips_seeds_whose_budget_is_spent(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    runs = tmp_path / "runs"
    for seed in (1, 2):
        run_dir = make_run(runs, f"learn-reach_target-cpu-small-s{seed}", [0.0, 1.0])
        run_budget.save_budget(run_dir, run_budget.Budget([[LAUNCHED, LAUNCHED + 60]]))

    def no_launch(*_args, **_kwargs):
        raise AssertionError("launched a run whose budget was spent")

    monkeypatch.setattr(learning, "run_budgeted", no_launch)
    argv = ["--seeds", "2", "--minutes", "1", "--runs-dir", str(runs), "--results-dir", str(tmp_path / "res")]
    assert learning.main(argv) == 0
    assert (tmp_path / "res" / "reach_target-cpu-small.csv").exists()


def test_cli_plot_only_writes_seed_and_aggregate_results(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    runs, results = tmp_path / "runs", tmp_path / "results"
    make_run(runs, "learn-push_button-cpu-small-demo25-s1", [0.0, 0.5, 0.9])
    make_run(runs, "learn-push_button-cpu-small-demo25-s2", [0.1, 0.8], minutes_apart=3.0)
    argv = ["--task", "push_button", "--tag", "demo25", "--seeds", "3", "--plot-only",
            "--runs-dir", str(runs), "--results-dir", str(results)]
    assert learning.main(argv) == 0
    stem = results / "push_button-cpu-small-demo25"
    with Path(f"{stem}.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == learning_curves.AGGREGATE_FIELDS
    assert [float(r["success_rate"]) for r in rows] == [0.0, 0.5]
    assert [float(r["minutes"]) for r in rows] == pytest.approx([3.0, 6.0])
    with Path(f"{stem}-s2.csv").open() as f:
        assert next(csv.reader(f)) == learning_curves.CURVE_FIELDS
    assert Path(f"{stem}.png").stat().st_size > 0
    assert not Path(f"{stem}-s3.csv").exists()
    out = capsys.readouterr().out
    assert "learn-push_button-cpu-small-demo25-s3: no evaluations" in out
    assert "| worst seed (per eval) |" in out


def test_per_run_plot_still_writes_the_learning_curve(tmp_path: Path) -> None:
    run_dir = make_run(tmp_path, "one", [0.0, 0.4])
    assert learning_curves.plot(run_dir) == run_dir / "learning_curve.png"
    with (run_dir / "learning_curve.csv").open() as f:
        assert next(csv.reader(f)) == learning_curves.CURVE_FIELDS
    assert learning_curves.plot(tmp_path / "empty") is None


def test_robot_seeds_combine_from_their_csvs_even_when_run_in_other_sessions(tmp_path: Path, capsys) -> None:
    """bench/robot_learning.py: seed 1 ran last week (only its CSV is left), seed 2 runs now."""
    spec = importlib.util.spec_from_file_location("bench_robot_learning", REPO / "bench" / "robot_learning.py")
    robot_learning = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(robot_learning)
    runs, results = tmp_path / "runs", tmp_path / "results"
    make_run(runs, "learn-robot-reach-robot-s2", [0.0, 0.6, 0.9])
    results.mkdir()
    old = [
        {"minutes": 1.5, "env_steps": 0, "learner_step": 0, "weights_version": 1, "success_rate": 0.0, "episodes": 10},
        {
            "minutes": 6.0,
            "env_steps": 74,
            "learner_step": 50,
            "weights_version": 6,
            "success_rate": 0.5,
            "episodes": 20,
        },
    ]
    learning_curves.write_csv(results / "robot-reach-robot-s1.csv", old, learning_curves.CURVE_FIELDS)
    assert learning_curves.read_curve_csv(results / "robot-reach-robot-s1.csv") == old
    learning_curves.write_csv(
        results / "robot-reach-robot-slow-s3.csv", old[:1], learning_curves.CURVE_FIELDS
    )
    args = robot_learning.parse_args(
        ["--seed", "2", "--plot-only", "--runs-dir", str(runs), "--results-dir", str(results)]
    )
    assert robot_learning.write_results(args)
    with (results / "robot-reach-robot.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [float(r["success_rate"]) for r in rows] == [0.0, 0.5]  # the worst seed, over the evaluations both have
    assert [int(r["seeds"]) for r in rows] == [2, 2]
    assert (results / "robot-reach-robot-s2.csv").exists() and (results / "robot-reach-robot.png").stat().st_size > 0
    assert "| worst seed (per eval) |" in capsys.readouterr().out
