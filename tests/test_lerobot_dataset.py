"""LeRobot v3.0 export and import: a third-party checker passes the dataset, every array reads back as
recorded, and import gives back demo files the demo source learns the same keyframes and actions from.

Two short scripted reach_target demos (two cameras, 32 px) are the source; a run directory with
evaluation episodes written by the evaluator's own writer stands in for a run.
"""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import run_c2farm as c2farm
from PIL import Image

from actors.demos import demo_to_transitions, load_demo
from actors.demos.augmentation import SUCCESS_REWARD
from actors.demos.generate import generate_demos
from actors.demos.keyframes import demo_keyframes
from protocol import lerobot_demo
from protocol.episode_file import write_episode_mcap
from protocol.lerobot_v3 import DatasetWriter, read_dataset
from protocol.observation import depth_to_points

CAMERAS = ("front", "wrist")


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> tuple[list, Path]:
    """Two scripted demos as MCAP files, exported with ``c2farm export lerobot``."""
    root = tmp_path_factory.mktemp("lerobot")
    summary = generate_demos("reach_target", 2, 1, root / "demos", cameras=CAMERAS, image_size=32, progress=False)
    code, stdout, stderr = c2farm("export", "lerobot", "--demos", str(root / "demos"), "--out", str(root / "ds"),
                                  "--repo-id", "c2farm/reach_target")
    assert code == 0, stderr
    assert "2 episodes" in stdout
    return [load_demo(p) for p in summary.written], root / "ds"


def doctor(root: Path) -> dict:
    """``lerobot-doctor ROOT --ci``: its JSON report; asserts it passed (exit 0: no check FAILed)."""
    done = subprocess.run([str(Path(sys.executable).parent / "lerobot-doctor"), str(root), "--ci"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    report = json.loads(done.stdout)
    assert report["summary"]["FAIL"] == 0 and report["format_version"] == "v3"
    return report


def test_lerobot_doctor_passes_the_export(exported):
    _, root = exported
    report = doctor(root)
    assert report["total_episodes"] == 2 and report["codebase_version"] == "v3.0"


def test_every_parquet_reads_back_as_the_demos_recorded(exported):
    demos, root = exported
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["robot_type"] == "franka_panda" and info["fps"] == 20
    assert info["repo_id"] == "c2farm/reach_target" and info["total_episodes"] == 2
    assert info["features"]["observation.state"]["names"] == lerobot_demo.STATE_NAMES
    assert info["features"]["observation.images.front"]["shape"] == [32, 32, 3]
    data = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet").to_pydict()
    episodes = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    tasks = pq.read_table(root / "meta" / "tasks.parquet").to_pylist()
    assert tasks == [{"task_index": 0, "task": "reach_target"}]
    assert info["total_frames"] == len(data["index"]) == sum(len(d.observations) for d in demos)
    assert data["index"] == list(range(info["total_frames"]))
    for e, (demo, row) in enumerate(zip(demos, episodes)):
        n, lo = len(demo.observations), row["dataset_from_index"]
        assert (row["episode_index"], row["length"], row["dataset_to_index"], row["tasks"]) == (e, n, lo + n,
                                                                                               ["reach_target"])
        assert row["c2farm/seed"] == demo.seed and row["c2farm/waypoint_frames"] == demo.waypoint_frames
        frames = range(lo, lo + n)
        assert [data["frame_index"][i] for i in frames] == list(range(n))
        assert all(data["episode_index"][i] == e and data["task_index"][i] == 0 for i in frames)
        assert np.array_equal(np.array([data["timestamp"][i] for i in frames]), (np.arange(n) / 20).astype(np.float32))
        keyframes = demo_keyframes(demo)
        for t, i in enumerate(frames):
            o = demo.observations[t]
            for c in CAMERAS:
                png = data[f"observation.images.{c}"][i]["bytes"]
                assert np.array_equal(np.asarray(Image.open(io.BytesIO(png))), o.cameras[c].rgb)
                k = np.array(data[f"observation.intrinsics.{c}"][i], np.float32).reshape(3, 3)
                ext = np.array(data[f"observation.extrinsics.{c}"][i], np.float32).reshape(4, 4)
                assert np.array_equal(k, o.cameras[c].intrinsics) and np.array_equal(ext, o.cameras[c].extrinsics)
                depth = np.array(data[f"observation.depth.{c}"][i], np.float32).reshape(32, 32)
                assert np.allclose(depth_to_points(depth, k.astype(np.float64), ext.astype(np.float64)),
                                   o.cameras[c].points, atol=1e-5)
            state = np.concatenate([o.gripper_pose, [o.gripper_open], o.finger_positions, o.joint_positions,
                                    o.joint_velocities]).astype(np.float32)
            assert np.array_equal(np.array(data["observation.state"][i], np.float32), state)
            target = demo.observations[next((k for k in keyframes if k > t), t)]
            assert np.array_equal(np.array(data["action"][i], np.float32),
                                  np.concatenate([target.gripper_pose, [target.gripper_open]]).astype(np.float32))
            assert data["is_keyframe"][i] == (t in keyframes) and data["next.done"][i] == (t == n - 1)
            assert data["next.reward"][i] == (SUCCESS_REWARD if t == n - 1 else 0.0)
    stats = json.loads((root / "meta" / "stats.json").read_text())
    assert set(stats) == set(info["features"])
    assert np.array(stats["observation.images.front"]["mean"]).shape == (3, 1, 1)
    assert stats["action"]["count"] == [info["total_frames"]]
    states = np.array(data["observation.state"], np.float64)
    assert np.allclose(stats["observation.state"]["mean"], states.mean(axis=0))
    assert np.allclose(stats["observation.state"]["min"], states.min(axis=0))


def test_import_gives_back_demo_files_with_the_same_keyframes_and_actions(exported, tmp_path):
    demos, root = exported
    code, stdout, stderr = c2farm("import", "lerobot", str(root), "--out", str(tmp_path / "demos"))
    assert code == 0, stderr
    assert "reach_target-front+wrist-32px" in stdout  # where a run of this task and cameras looks for them
    files = sorted((tmp_path / "demos").glob("*.mcap"))
    assert len(files) == 2
    for original, path in zip(demos, files):
        back = load_demo(path)
        assert (back.task, back.seed, back.success, back.waypoint_frames, back.keyframes, back.control_hz) == (
            original.task, original.seed, original.success, original.waypoint_frames, original.keyframes, 20)
        assert demo_keyframes(back) == demo_keyframes(original)
        for a, b in zip(original.observations, back.observations):
            assert np.array_equal(a.gripper_pose, b.gripper_pose) and a.gripper_open == b.gripper_open
            assert np.array_equal(a.joint_velocities, b.joint_velocities) and a.step == b.step
            for c in CAMERAS:
                assert np.array_equal(a.cameras[c].rgb, b.cameras[c].rgb)
                assert np.allclose(a.cameras[c].points, b.cameras[c].points, atol=1e-5)
        for x, y in zip(demo_to_transitions(original.observations, demo_keyframes(original)),
                        demo_to_transitions(back.observations, demo_keyframes(back))):
            assert np.array_equal(x.actions, y.actions) and np.array_equal(x.rewards, y.rewards)


def test_a_runs_evaluation_episodes_export_with_the_poses_the_policy_chose(exported, tmp_path):
    demos, _ = exported
    run = tmp_path / "run"
    (run / "eval").mkdir(parents=True)
    (run / "config.yaml").write_text("run:\n  run_id: r\n")
    demo = demos[0]
    frames = [demo.observations[0]] + [demo.observations[k] for k in demo_keyframes(demo)]
    actions = [lerobot_demo._pose(o) for o in frames[1:]]
    write_episode_mcap(run / "eval" / "v000003-seed7.mcap", frames, task="reach_target", seed=7, success=True,
                       actions=actions, end_reason="success")
    code, _, stderr = c2farm("export", "lerobot", "--run", str(run), "--out", str(tmp_path / "ds"))
    assert code == 0, stderr
    doctor(tmp_path / "ds")
    episode = read_dataset(tmp_path / "ds").episode(0)
    assert np.array_equal(episode.columns["action"], np.stack(actions + [lerobot_demo._pose(frames[-1])]))
    assert episode.columns["is_keyframe"].reshape(-1).tolist() == [False] + [True] * (len(frames) - 1)
    code, _, stderr = c2farm("import", "lerobot", str(tmp_path / "ds"), "--out", str(tmp_path / "back"))
    assert code == 0, stderr
    back = load_demo(next((tmp_path / "back").glob("*.mcap")))
    assert back.end_reason == "success" and back.keyframes is None and back.seed == 7
    assert all(np.array_equal(a, b) for a, b in zip(back.actions, actions)) and len(back.actions) == len(actions)


def test_a_dataset_without_depth_cannot_be_imported_and_says_so_in_one_line(exported, tmp_path):
    demos, _ = exported
    keep = {k: ft for k, ft in lerobot_demo.features(list(CAMERAS), 32).items()
            if not k.startswith("observation.depth.")}
    writer = DatasetWriter(tmp_path / "ds", 20, keep, lerobot_demo.ROBOT_TYPE, "no-depth")
    episode = lerobot_demo.demo_episode(demos[0], demo_keyframes(demos[0]), SUCCESS_REWARD)
    episode.columns = {k: v for k, v in episode.columns.items() if k in keep}
    writer.add(episode)
    writer.finish()
    code, stdout, stderr = c2farm("import", "lerobot", str(tmp_path / "ds"), "--out", str(tmp_path / "demos"))
    assert code == 2 and not stdout
    assert len(stderr.strip().splitlines()) == 1 and stderr.startswith("c2farm: import lerobot: "), stderr
    assert "observation.depth.front" in stderr and "observation.depth.wrist" in stderr
    assert not (tmp_path / "demos").exists()


def test_bad_sources_and_destinations_are_one_line_and_exit_2(exported, tmp_path):
    _, root = exported
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("run:\n  run_id: r\n")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    bad = (["--demos", str(tmp_path / "missing")], ["--run", str(run), "--episodes", "train"], ["--run", str(run)],
           ["--run", str(tmp_path)], ["--demos", str(root), "--out", str(tmp_path / "full")])
    for argv in bad:
        out = [] if "--out" in argv else ["--out", str(tmp_path / "out")]
        code, stdout, stderr = c2farm("export", "lerobot", *argv, *out)
        assert code == 2 and not stdout, argv
        assert len(stderr.strip().splitlines()) == 1 and stderr.startswith("c2farm: export lerobot: "), stderr
    assert "no training episodes" in c2farm("export", "lerobot", "--run", str(run), "--episodes", "train",
                                            "--out", str(tmp_path / "out"))[2]
    assert not (tmp_path / "out").exists()
    for argv in ([str(tmp_path / "missing")], [str(root), "--task", "juggle"]):
        code, _, stderr = c2farm("import", "lerobot", *argv, "--out", str(tmp_path / "demos"))
        assert code == 2 and len(stderr.strip().splitlines()) == 1, stderr
    shutil.rmtree(tmp_path / "full")
