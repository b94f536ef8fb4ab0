"""Demo files: write, reload, augment; broken files fail with the file's name; the CLI writes demos."""

import argparse
import json

import numpy as np
import pytest
from mcap.reader import make_reader

from actors.demos import DemoFileError, demo_to_transitions, discover_keyframes, load_demo
from actors.demos.cli import add_arguments, run
from actors.demos.generate import generate_demos


@pytest.fixture(scope="module")
def demo_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("demos")
    summary = generate_demos("pick_and_lift", 1, 4, out, cameras=("front", "wrist"), image_size=48, progress=False)
    return summary


def test_generated_demo_reloads_as_observations(demo_file):
    demo = load_demo(demo_file.written[0])
    assert demo.task == "pick_and_lift" and demo.seed == demo_file.seeds[0] and demo.success
    assert len(demo.waypoint_frames) == 3
    obs = demo.observations
    assert set(obs[0].cameras) == {"front", "wrist"}
    assert obs[0].cameras["front"].rgb.shape == (48, 48, 3) and obs[0].cameras["front"].rgb.dtype == np.uint8
    assert [o.step for o in obs][:1] == [0] and obs[-1].step == 3
    assert discover_keyframes(obs) == demo.waypoint_frames


def test_reloaded_points_match_the_recorded_ones(demo_file, tmp_path):
    from actors.demos.generate import record_demo
    from actors.panda_env import PandaEnv
    from actors.sim import SimConfig
    env = PandaEnv(SimConfig(task="pick_and_lift", cameras=("front", "wrist"), image_size=48))
    live = record_demo(env, demo_file.seeds[0])
    env.close()
    loaded = load_demo(demo_file.written[0])
    assert len(live.observations) == len(loaded.observations)
    for a, b in zip(live.observations[::7], loaded.observations[::7]):
        assert np.array_equal(a.joint_positions, b.joint_positions) and a.gripper_open == b.gripper_open
        for cam in a.cameras:
            assert np.array_equal(a.cameras[cam].rgb, b.cameras[cam].rgb)
            assert np.allclose(a.cameras[cam].points, b.cameras[cam].points, atol=1e-5)


def test_file_has_foxglove_channels_and_episode_metadata(demo_file):
    with open(demo_file.written[0], "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.name for s in summary.schemas.values()}
        topics = {c.topic for c in summary.channels.values()}
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert {
        "foxglove.RawImage",
        "foxglove.CameraCalibration",
        "foxglove.PointCloud",
        "foxglove.FrameTransforms",
        "foxglove.JointStates",
    } <= schemas
    assert all(c.schema_id for c in summary.channels.values())  # no schemaless channel for Foxglove to flag
    assert {"/front/image", "/wrist/calibration", "/front/points", "/tf", "/joint_states"} <= topics
    assert meta["episode"]["task"] == "pick_and_lift" and json.loads(meta["episode"]["success"]) is True


def test_demo_augmentation_gives_keyframe_to_keyframe_episodes(demo_file):
    demo = load_demo(demo_file.written[0])
    kf = discover_keyframes(demo.observations)
    episodes = demo_to_transitions(demo.observations, kf, every_n=10)
    assert len(episodes) == len(range(0, len(demo.observations) - 1, 10))
    first = episodes[0]
    assert len(first.observations) == len(kf) + 1 and first.actions.shape == (len(kf), 8)
    assert [o.step for o in first.observations] == list(range(len(kf) + 1))
    assert first.rewards.tolist() == [0.0] * (len(kf) - 1) + [100.0] and first.terminals[-1] and not first.terminals[0]
    assert np.allclose(first.actions[0][:7], demo.observations[kf[0]].gripper_pose)
    for ep in episodes:
        assert ep.observations[0].step == 0 and ep.actions.dtype == np.float32
    assert demo.observations[kf[0]].step != 0 or kf[0] == 0  # originals untouched by the step renumbering


def test_truncated_or_garbage_files_name_the_file(demo_file, tmp_path):
    data = open(demo_file.written[0], "rb").read()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(DemoFileError, match="cut.mcap"):
        load_demo(cut)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(DemoFileError, match="junk.mcap"):
        load_demo(junk)
    with pytest.raises(DemoFileError, match="missing.mcap"):
        load_demo(tmp_path / "missing.mcap")


def test_cli_writes_demos_and_rejects_unknown_tasks(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert run(parser.parse_args(["--task", "reach_target", "--episodes", "1", "--out", str(tmp_path),
                                  "--cameras", "front", "--image-size", "32", "--no-progress"])) == 0
    assert len(list(tmp_path.glob("reach_target_seed*.mcap"))) == 1
    assert run(parser.parse_args(["--task", "nope", "--out", str(tmp_path), "--no-progress"])) == 2
    assert "reach_target" in capsys.readouterr().err
