"""bench/grid_study.py: each grid is its task's entry with the grid swapped, and the table heads with the worst seed."""

from __future__ import annotations

import csv
import importlib.util
import sys
from pathlib import Path

import learning_curves  # bench/learning_curves.py
import pytest

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("bench_grid_study", REPO / "bench" / "grid_study.py")
grid_study = importlib.util.module_from_spec(_spec)
sys.modules["bench_grid_study"] = grid_study
_spec.loader.exec_module(grid_study)


def write_seed(results: Path, grid: str, seed: int, rates: list[float], minutes_apart: float) -> None:
    curve = [{"minutes": minutes_apart * (k + 1), "env_steps": 200 * k, "learner_step": 50 * k,
              "weights_version": 1 + k, "success_rate": r, "episodes": 20} for k, r in enumerate(rates)]
    learning_curves.write_csv(results / f"lift_lid-cpu-small-lid-grid-{grid}-s{seed}.csv", curve,
                              learning_curves.CURVE_FIELDS)


def test_each_grid_is_the_entry_with_its_voxels_per_depth_and_last_voxel():
    edges = {}
    for grid in grid_study.GRIDS:
        cfg = grid_study.grid_config("lift_lid", grid)
        assert "x".join([str(cfg.voxel_size)] * cfg.depths) == grid.replace("-fine", "").replace("-", "x")
        edges[grid] = 2 * cfg.offset(cfg.depths - 1) / cfg.voxel_size
    # the paper's (16,16) and the entry's (8,8,8) end on the same 1.9 cm voxel; (8,8) is twice as coarse
    assert edges["16-16"] == pytest.approx(edges["8-8-8"]) == pytest.approx(0.01875)
    assert edges["8-8"] == pytest.approx(2 * edges["16-16"]) and edges["16-16-16"] < edges["8-8-8-fine"] < 0.0188


def test_the_table_orders_grids_by_their_worst_seed_and_a_seed_that_never_got_there_is_the_worst(tmp_path, capsys):
    write_seed(tmp_path, "8-8-8", 1, [0.0, 0.5, 0.8, 0.9], 1.0)      # 80 % at 3 min
    write_seed(tmp_path, "8-8-8", 2, [0.0, 0.2, 0.5, 0.6, 0.85], 1.0)  # 80 % at 5 min: the grid's worst
    write_seed(tmp_path, "16-16", 1, [0.0, 0.9], 2.0)                  # 80 % at 4 min
    write_seed(tmp_path, "16-16", 2, [0.0, 0.3, 0.4], 2.0)             # never: the grid's worst, last in the table
    assert grid_study.main(["--summary", "--results-dir", str(tmp_path), "--seeds", "2",
                            "--grids", "16-16", "8-8-8", "8-8"]) == 0
    lines = (tmp_path / "grid_study-lift_lid.md").read_text().splitlines()
    rows = [line for line in lines if line.startswith("| ") and not line.startswith("| grid")]
    assert rows[0].startswith("| **(8,8,8)**, 2 seeds | 1.88 cm |") and "2 (worst)" in rows[0]
    assert "**5.0, 800, 200**" in rows[0]
    assert rows[2].startswith("| **(16,16)**, 2 seeds | 1.88 cm |") and "2 (worst)" in rows[2]
    assert "**not reached**" in rows[2] and "40 %" in rows[2]
    assert lines[-1] == "No seed has run yet: 8-8."
    with (tmp_path / "grid_study-lift_lid.csv").open(newline="") as f:
        by_seed = {(r["grid"], r["seed"]): r for r in csv.DictReader(f)}
    assert by_seed[("8-8-8", "1")]["updates"] == "100" and by_seed[("16-16", "2")]["minutes"] == ""


def test_a_grid_or_task_outside_the_study_is_one_line_before_anything_runs(capsys):
    with pytest.raises(SystemExit) as exit_:
        grid_study.parse_args(["--grids", "16-16", "32-32"])
    assert exit_.value.code == 2 and "unknown grid(s) 32-32" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        grid_study.parse_args(["--task", "stack_wine"])
    with pytest.raises(SystemExit):
        grid_study.parse_args(["--threshold", "80"])


def test_each_run_is_the_entrys_grid_lever_stopped_at_the_threshold():
    args = grid_study.parse_args(["--task", "put_in_bin", "--threshold", "0.7"])
    argv = grid_study.learning_args(args, grid_study.variant("put_in_bin", "16-16"), 2)
    assert argv[argv.index("--tag") + 1] == "release-grid-16-16" and argv[argv.index("--stop-at") + 1] == "0.7"
    assert "qattention.voxel_size=16" in argv and "learner.acting_average=0.99" in argv


def test_a_study_of_one_grid_keeps_the_other_grids_rows_and_the_update_costs_timed_before(tmp_path):
    write_seed(tmp_path, "16-16", 1, [0.0, 0.9], 2.0)
    (tmp_path / "grid_study-lift_lid.csv").write_text(  # an earlier --costs run's record
        "grid,voxels,update_s,seed\n16-16,\"(16,16)\",0.88,1\n8-8,\"(8,8)\",0.18,1\n")
    write_seed(tmp_path, "8-8", 1, [0.0, 0.5, 0.85], 1.0)  # the grid studied now
    assert grid_study.main(["--summary", "--results-dir", str(tmp_path), "--seeds", "1", "--grids", "8-8"]) == 0
    rows = [line for line in (tmp_path / "grid_study-lift_lid.md").read_text().splitlines()
            if line.startswith("| **")]
    assert [row.split("|")[1].strip() for row in rows] == ["**(8,8)**, 1 seed", "**(16,16)**, 1 seed"]
    assert [row.split("|")[3].strip() for row in rows] == ["0.18", "0.88"]
