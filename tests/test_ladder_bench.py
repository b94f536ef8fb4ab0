"""bench/ladder.py: every rung is a config the run accepts, and the table puts each task's worst seed first."""

from __future__ import annotations

import csv
import importlib.util
import json
import sys
from pathlib import Path

import learning_curves  # bench/learning_curves.py
import pytest

from actors.sim.task_specs import TASK_SPECS

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("bench_ladder", REPO / "bench" / "ladder.py")
ladder = importlib.util.module_from_spec(_spec)
sys.modules["bench_ladder"] = ladder  # dataclasses look their module up here
_spec.loader.exec_module(ladder)


def write_seed(results: Path, task: str, seed: int, rates: list[float], minutes_apart: float) -> None:
    curve = [
        {
            "minutes": minutes_apart * (k + 1),
            "env_steps": 200 * k,
            "learner_step": 50 * k,
            "weights_version": 1 + 5 * k,
            "success_rate": r,
            "episodes": 20,
        }
        for k, r in enumerate(rates)
    ]
    learning_curves.write_csv(results / f"{task}-cpu-small-ladder-s{seed}.csv", curve, learning_curves.CURVE_FIELDS)


def test_the_ladder_is_every_task_and_each_rung_a_config_the_run_accepts():
    from actors.sim.task_specs import TASKS

    assert tuple(ladder.RUNGS) == TASKS
    for rung in ladder.RUNGS.values():
        config = ladder.run_config(ladder.parse_args([]), rung)
        assert config.sim.task == rung.task
        assert not rung.overrides or rung.why, f"{rung.task}: a per-task entry says why"


def test_each_seed_is_a_learning_run_stopped_at_its_bar():
    args = ladder.parse_args(["--tasks", "stack_wine"])
    argv = ladder.learning_args(args, ladder.RUNGS["stack_wine"], 2)
    assert argv[argv.index("--stop-at") + 1] == "0.7" and argv[argv.index("--first-seed") + 1] == "2"
    assert argv[argv.index("--tag") + 1] == "ladder" and argv[argv.index("--minutes") + 1] == "60"


def test_the_table_puts_each_tasks_worst_seed_first_and_writes_md_csv_png(tmp_path):
    results = tmp_path / "results"
    write_seed(results, "push_button", 1, [0.0, 0.95, 1.0], 1.0)
    write_seed(results, "push_button", 2, [0.0, 0.5, 0.85, 0.9, 0.95], 1.0)  # the slowest to 90 %
    write_seed(results, "lift_lid", 1, [0.0, 0.85, 0.9], 2.0)
    write_seed(results, "lift_lid", 2, [0.0, 0.2, 0.4], 2.0)  # never reached 80 %
    args = ladder.parse_args(["--tasks", "push_button", "lift_lid", "open_drawer", "--seeds", "2", "--summary",
                              "--results-dir", str(results)])
    assert ladder.main(["--tasks", "push_button", "lift_lid", "open_drawer", "--seeds", "2", "--summary",
                        "--results-dir", str(results)]) == 0
    lines = (results / "ladder.md").read_text().splitlines()
    push = lines.index(next(line for line in lines if line.startswith("| **push_button**")))
    assert "| 2 (worst) |" in lines[push] and "4.0, 600, 150" in lines[push]  # seed 2 reached 90 % at 4 min
    assert lines[push + 1].startswith("|  |  |  | 1 |")
    lid = next(line for line in lines if line.startswith("| **lift_lid**"))
    assert "| 2 (worst) | not reached | not reached | 40 % |" in lid
    revision = TASK_SPECS["open_drawer"].revision
    assert lines[-1] == f"No seed has run yet at the task's current revision: open_drawer (revision {revision})."
    with (results / "ladder.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["task"], r["seed"]) for r in rows] == [("push_button", "2"), ("push_button", "1"),
                                                       ("lift_lid", "2"), ("lift_lid", "1")]
    assert rows[0]["demos"] == "10" and rows[0]["cameras"] == "front" and rows[0]["grid"] == "(8,8,8)"
    assert (results / "ladder.png").stat().st_size > 0
    assert args.seeds == 2


def test_an_unknown_task_is_one_line_before_anything_runs(capsys):
    with pytest.raises(SystemExit) as exit_:
        ladder.parse_args(["--tasks", "lift_lid", "fold_laundry"])
    assert exit_.value.code == 2 and "unknown task(s) fold_laundry" in capsys.readouterr().err


def test_a_recorded_seed_is_not_run_again_even_where_its_run_directory_is_gone(tmp_path, monkeypatch):
    """The CSVs are the record (committed); the runs dir is this machine's scratch."""
    results = tmp_path / "results"
    write_seed(results, "push_button", 1, [0.0, 0.95, 1.0], 1.0)
    ran = []
    monkeypatch.setattr(ladder.learning, "run_each", lambda runs: ran.extend(name for name, _ in runs) or [])
    assert ladder.main(["--tasks", "push_button", "--seeds", "2", "--runs-dir", str(tmp_path / "runs"),
                        "--results-dir", str(results)]) == 0
    assert ran == ["push_button seed 2"]


def test_each_seed_is_shown_with_its_learners_speed_and_the_cpu_it_ran_on(tmp_path):
    """Minutes depend on the host: the table says, per seed, how fast its learner went and on which CPU flags."""
    results = tmp_path / "results"
    write_seed(results, "push_button", 1, [0.0, 0.95, 1.0], 1.0)  # 100 updates in 3 minutes
    write_seed(results, "push_button", 2, [0.0, 0.5, 0.95], 2.0)  # 100 updates in 6 minutes, no machine record
    (results / "push_button-cpu-small-ladder-s1.machine.json").write_text(
        '{"cpu": "AMD EPYC, 2 cores, avx2 avx512f avx512_bf16", "git_commit": "50d60a89f15", "torch": "2.13.0+cpu"}')
    assert ladder.main(["--tasks", "push_button", "--seeds", "2", "--summary", "--results-dir", str(results)]) == 0
    lines = (results / "ladder.md").read_text().splitlines()
    worst = lines.index(next(line for line in lines if line.startswith("| **push_button**")))
    assert lines[worst].endswith("| 0.28, not recorded |")  # seed 2
    assert lines[worst + 1].endswith("| 0.56, avx2 avx512f avx512_bf16 |")  # seed 1
    with (results / "ladder.csv").open() as f:
        rows = {r["seed"]: r for r in csv.DictReader(f)}
    assert rows["1"]["cpu"] == "AMD EPYC, 2 cores, avx2 avx512f avx512_bf16" and rows["1"]["commit"] == "50d60a8"
    assert rows["2"]["cpu"] == "" and rows["2"]["updates_per_s"] == "0.28"


def test_a_seeds_machine_record_is_its_runs_cpu_commit_and_torch(tmp_path):
    run_dir = tmp_path / "runs" / "learn-push_button-cpu-small-s1"
    run_dir.mkdir(parents=True)
    (run_dir / "versions.json").write_text(
        '{"python": "3.11.7", "cpu": "AMD EPYC, 2 cores, avx2", "torch": "2.13.0+cpu", "git_commit": "abc"}')
    out = tmp_path / "push_button-cpu-small-s1.machine.json"
    ladder.learning.record_machine(run_dir, out)
    assert json.loads(out.read_text()) == {"cpu": "AMD EPYC, 2 cores, avx2", "git_commit": "abc", "torch": "2.13.0+cpu"}
    ladder.learning.record_machine(tmp_path / "runs" / "gone", out)  # a run directory gone keeps the record
    assert json.loads(out.read_text())["cpu"] == "AMD EPYC, 2 cores, avx2"
