"""bench/ablation.py: every lever is a valid config, and the table times each seed and the slowest."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import pytest
import run_budget  # bench/run_budget.py

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("bench_ablation", REPO / "bench" / "ablation.py")
ablation = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ablation)


def curve(*points: tuple[float, int, float]) -> list[dict]:
    """(minutes, env steps, success) per evaluation, 50 updates apart, 20 episodes each."""
    return [{"minutes": m, "env_steps": s, "learner_step": 50 * k, "weights_version": 1 + 5 * k, "success_rate": r,
             "episodes": 20} for k, (m, s, r) in enumerate(points)]


@pytest.mark.parametrize("variant", list(ablation.LEVERS))
def test_every_lever_is_a_config_the_run_accepts(variant):
    from deploy.config import load_config
    from deploy.config_loader import parse_override

    config = load_config(preset="cpu-small", overrides=tuple(parse_override(o) for o in ablation.LEVERS[variant]))
    if variant == "base":  # the reference's algorithm: no demo share, one-step, no top-K, no margin
        assert (config.replay.demo_fraction, config.replay.n_step, config.actor.reachable_top_k,
                config.qattention.demo_margin) == (0.0, 1, 0, 0.0)


def test_the_grid_study_changes_only_the_grid_of_each_entry():
    """lid-grid-8-8-8 is lift_lid's entry itself, release-grid-8-8-8 put_in_bin's; the other grids differ
    from them in the three grid fields alone."""
    assert set(ablation.LEVERS["lid-grid-8-8-8"]) == set(ablation.LEVERS["lid-entry-untimed-demos-0.5"])
    assert set(ablation.LEVERS["release-grid-8-8-8"]) == set(ablation.LEVERS["lid-heads-1-acting-0.99"])
    for entry in ("lid", "release"):
        for grid in ("16-16", "8-8", "16-16-16"):
            changed = set(ablation.LEVERS[f"{entry}-grid-{grid}"]) ^ set(ablation.LEVERS[f"{entry}-grid-8-8-8"])
            assert {item.split("=")[0] for item in changed} <= {"qattention.voxel_size", "qattention.depths",
                                                                 "qattention.bounds_offset"}


def test_the_table_times_each_seed_and_heads_with_the_slowest():
    results = {
        "default": {1: curve((1.0, 100, 0.0), (5.0, 500, 0.95)), 2: curve((1.0, 100, 0.6), (6.0, 700, 0.9))},
        "base": {1: curve((1.0, 100, 0.0), (5.0, 500, 0.95)), 2: curve((1.0, 100, 0.0), (6.0, 700, 0.4))},
    }
    rows = ablation.table(results, [0.5, 0.9]).splitlines()
    assert rows[0] == "| variant | seed | first ≥ 50 % | first ≥ 90 % | end | evals | samples/insert |"
    slowest_default = next(r for r in rows if r.startswith("| **default** | slowest"))
    assert "6.0 min, 700 env steps" in slowest_default.split("|")[4] and "5.0 min" in slowest_default.split("|")[3]
    slowest_base = next(r for r in rows if r.startswith("| **base** | slowest"))
    assert slowest_base.split("|")[4].strip() == "not reached"  # seed 2 never got to 90 %
    assert slowest_base.split("|")[5].strip() == "40 %"


def test_seeds_interleave_and_each_run_is_a_tagged_learning_run():
    args = ablation.parse_args(["--task", "push_button", "--variants", "default", "no-margin", "--seeds", "2"])
    argv = ablation.learning_args(args, "no-margin", 2)
    assert argv[argv.index("--tag") + 1] == "no-margin" and argv[argv.index("--first-seed") + 1] == "2"
    assert "qattention.demo_margin=0.0" in argv


def test_an_unknown_lever_is_one_line_before_anything_runs(capsys):
    with pytest.raises(SystemExit) as exit_:
        ablation.parse_args(["--variants", "default", "more-magic"])
    assert exit_.value.code == 2 and "unknown variant(s) more-magic" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ablation.parse_args(["--stop-at", "90"])  # a percentage where a rate belongs
    assert "--stop-at must be a success rate in (0, 1]" in capsys.readouterr().err


def test_a_run_id_the_launcher_would_refuse_is_one_line_before_anything_runs(capsys):
    """The variant names the run: on the longest task a long name passes 64 characters, which the launcher refuses."""
    with pytest.raises(SystemExit) as exit_:
        ablation.parse_args(["--task", "put_item_in_drawer", "--variants", "shoulders-heads-1-acting-0.99"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "'learn-put_item_in_drawer-cpu-small-shoulders-heads-1-acting-0.99-s1'" in err
    assert "(67 characters) is not a valid id" in err
    ablation.parse_args(["--task", "put_item_in_drawer", "--variants", "drawer-entry-timed"])  # 52: accepted


def test_the_ratio_a_run_achieved_is_read_from_the_learners_log(tmp_path):
    metrics = tmp_path / "run" / "metrics"
    metrics.mkdir(parents=True)
    (metrics / "learner.csv").write_text("step,loss,replay_samples_per_insert\n10,0.5,3.2\n20,0.4,3.9\n")
    assert ablation.achieved_samples_per_insert(tmp_path / "run") == 3.9
    assert ablation.achieved_samples_per_insert(tmp_path / "never-ran") is None
    results = {"spi-4": {1: curve((1.0, 100, 0.0), (5.0, 500, 0.95))}}
    results["spi-4"][1][-1]["samples_per_insert"] = 3.9
    assert ablation.table(results, [0.9]).splitlines()[2].endswith("| 2 | 3.90 |")


def test_each_variants_aggregate_holds_every_seed_of_it(tmp_path, monkeypatch):
    """Seeds interleave, so each learning run sees one seed; the ablation then combines them all."""
    import csv

    runs, results = tmp_path / "runs", tmp_path / "results"
    for seed, rates in ((1, (0.0, 0.95, 1.0)), (2, (0.0, 0.5, 0.8, 0.9, 0.95))):
        run_dir = runs / f"learn-push_button-cpu-small-default-s{seed}"
        (run_dir / "metrics").mkdir(parents=True)
        (run_dir / "launched_at").write_text("0\n")
        rows = ["time,learner_step,env_steps,episodes,success_rate"]
        rows += [f"{60 * (k + 1)},{50 * k},{100 * k},10,{r}" for k, r in enumerate(rates)]
        (run_dir / "metrics" / "eval.csv").write_text("\n".join(rows) + "\n")
    run_budget.save_budget(runs / "learn-push_button-cpu-small-default-s1",
                                  run_budget.Budget([[0.0, 180.0]], held_rate=0.9))
    # The runs are already on disk: the bench's own subprocess.run (bench/learning.py's run_each; only its:
    # matplotlib's first import runs fc-list through the real one) reports each as done.
    done = SimpleNamespace(run=lambda *a, **k: SimpleNamespace(returncode=0))
    monkeypatch.setattr(ablation.learning, "subprocess", done)
    argv = ["--task", "push_button", "--variants", "default", "--seeds", "2", "--stop-at", "0.9",
            "--stop-held", "2", "--runs-dir", str(runs), "--results-dir", str(results)]
    assert ablation.main(argv) == 0
    with (results / "push_button-cpu-small-default.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {int(r["seeds"]) for r in rows} == {2} and len(rows) == 5  # seed 1 held 100 % to the end
    assert [float(r["success_rate"]) for r in rows] == [0.0, 0.5, 0.8, 0.9, 0.95]


def test_seeds_run_a_few_at_a_time_all_reach_the_variants_aggregate(tmp_path):
    """Seed 1 ran yesterday, seed 2 today (``--first-seed 2 --seeds 1``): the aggregate and the table hold both."""
    import csv

    from learning_curves import curve_fields, read_curve_csv, write_csv

    results = tmp_path / "results"
    for seed, rates in ((1, (0.0, 0.9, 0.9)), (2, (0.0, 0.2, 0.6))):
        points = curve(*((1.0 + k, 100 * k, r) for k, r in enumerate(rates)))
        write_csv(results / f"push_button-cpu-small-no-margin-s{seed}.csv", points, curve_fields(points))
    before = (results / "push_button-cpu-small-no-margin-s1.csv").read_bytes()
    argv = ["--task", "push_button", "--variants", "no-margin", "--first-seed", "2", "--seeds", "1",
            "--thresholds", "0.5", "--runs-dir", str(tmp_path / "runs"), "--results-dir", str(results), "--summary"]
    assert ablation.main(argv) == 0
    with (results / "push_button-cpu-small-no-margin.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {int(r["seeds"]) for r in rows} == {2}
    assert [float(r["success_rate"]) for r in rows] == [0.0, 0.2, 0.6]  # the worst seed at each point
    assert (results / "push_button-cpu-small-no-margin-s1.csv").read_bytes() == before  # read back as it was
    assert read_curve_csv(results / "push_button-cpu-small-no-margin-s2.csv")[-1]["success_rate"] == 0.6
    table = (results / "ablation-push_button-cpu-small.md").read_text()
    assert "| no-margin | 1 |" in table and "| no-margin | 2 |" in table


def test_a_later_ablation_keeps_the_earlier_levers_rows_and_reads_seeds_back_from_their_csvs(tmp_path):
    """The table file is rewritten by every ablation: levers not named now come back from their seed CSVs,
    and so do the named lever's seeds once their run directories are gone (another machine)."""
    from learning_curves import curve_fields, write_csv

    results = tmp_path / "results"
    for variant, rates in (("no-margin", (0.0, 0.6, 0.9)), ("base", (0.0, 0.2))):
        points = curve(*((1.0 + k, 100 * k, r) for k, r in enumerate(rates)))
        write_csv(results / f"push_button-cpu-small-{variant}-s1.csv", points, curve_fields(points))
    write_csv(results / "push_button-cpu-small-base.csv", points, curve_fields(points))  # an aggregate: not a seed
    argv = ["--task", "push_button", "--variants", "no-margin", "--seeds", "1", "--thresholds", "0.5",
            "--runs-dir", str(tmp_path / "runs"), "--results-dir", str(results), "--summary"]
    assert ablation.main(argv) == 0
    now, _, earlier = (results / "ablation-push_button-cpu-small.md").read_text().partition("The other levers")
    assert "| no-margin | 1 | 2.0 min, 100 env steps, step 50 | 90 % at 3.0 min | 3 |" in now
    assert "| base | 1 | not reached | 20 % at 2.0 min | 2 |" in earlier and "no-margin" not in earlier


def test_a_summary_combines_seeds_from_other_machines_and_carries_the_one_that_held(tmp_path):
    """Seeds 1 and 3 ran elsewhere (only their CSVs are here): the aggregate holds both, and seed 1, which
    held 90 % twice as ``--stop-at`` reads it, keeps 90 % while seed 3 runs on."""
    import csv

    from learning_curves import curve_fields, write_csv

    results = tmp_path / "results"
    for seed, rates in ((1, (0.0, 0.9, 0.95)), (3, (0.0, 0.2, 0.5, 0.9, 0.9))):
        points = curve(*((1.0 + k, 100 * k, r) for k, r in enumerate(rates)))
        write_csv(results / f"push_button-cpu-small-no-margin-s{seed}.csv", points, curve_fields(points))
    argv = ["--task", "push_button", "--variants", "no-margin", "--seeds", "3", "--stop-at", "0.9",
            "--stop-held", "2", "--runs-dir", str(tmp_path / "runs"), "--results-dir", str(results), "--summary"]
    assert ablation.main(argv) == 0
    with (results / "push_button-cpu-small-no-margin.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [int(r["seeds"]) for r in rows] == [2] * 5 and [int(r["carried"]) for r in rows] == [0, 0, 0, 1, 1]
    assert [float(r["success_rate"]) for r in rows] == [0.0, 0.2, 0.5, 0.9, 0.9]  # the worst seed at each point
