"""The dashboard's run-file readers: incremental CSVs, thinning, memoised answers, state words,
PNG frames, pose projection, and the evaluation MCAP's new fields (actions, end reason)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from dashboard.episodes import encode_png, project, project_pose, quaternion_matrix
from dashboard.filecache import CsvTail, FileCache
from dashboard.history import MAX_POINTS, RunHistory, env_rates, thin
from dashboard.role_states import restart_policy, state_word, with_state_words
from protocol.observation import CameraFrame, Observation


def test_csv_tail_reads_only_complete_appended_lines(tmp_path):
    path = tmp_path / "eval.csv"
    tail = CsvTail(path)
    assert tail.read() == ([], [])
    path.write_text("step,loss\n1,0.5\n2,nan\n3,0.2")  # the last line is still being written
    header, rows = tail.read()
    assert header == ["step", "loss"] and rows == [[1.0, 0.5], [2.0, None]]
    with path.open("a") as f:
        f.write("5\n4,,\n")  # completes "3,0.25"; a row with the wrong number of cells is skipped
    assert tail.read()[1] == [[1.0, 0.5], [2.0, None], [3.0, 0.25]]
    path.write_text("step,loss\n9,1\n")  # replaced (shorter): read afresh
    assert tail.read()[1] == [[9.0, 1.0]]


def test_thin_keeps_first_and_last_and_at_most_max_points():
    series = {"x": list(range(5000)), "y": [i * 2 for i in range(5000)]}
    out = thin(series)
    assert len(out["x"]) <= MAX_POINTS and out["x"][0] == 0 and out["x"][-1] == 4999
    assert out["y"] == [2 * x for x in out["x"]]
    assert thin({"x": [1, 2]}) == {"x": [1, 2]}


def test_env_rates_between_evaluations():
    assert env_rates([110.0, 210.0, None, 410.0], [100, 300, 350, 700], started=100.0) == [10.0, 2.0, None, 2.0]


def test_history_is_memoised_until_a_file_changes(tmp_path):
    (tmp_path / "metrics").mkdir()
    csv = tmp_path / "metrics" / "eval.csv"
    csv.write_text("time,weights_version,env_steps,episodes,success_rate\n100,1,0,10,0\n")
    history = RunHistory(tmp_path)
    body, etag = history.history()
    assert body["eval"]["series"]["success_rate"] == [0] and body["learner"]["rows"] == 0
    assert body["replay_capacity"] is None and body["eval"]["series"]["minutes"] == [0.0]
    computed = history.cache.computed
    for _ in range(5):
        assert history.history()[1] == etag
    assert history.cache.computed == computed  # polls cost a stat, not a parse
    with csv.open("a") as f:
        f.write("160,2,50,20,0.25\n")
    body, etag2 = history.history()
    assert etag2 != etag and body["eval"]["series"]["env_steps"] == [0, 50]
    assert body["eval"]["series"]["env_steps_per_s"] == [None, pytest.approx(50 / 60, abs=1e-3)]


def test_file_cache_evicts_the_oldest():
    cache = FileCache(max_entries=2)
    for k in "abc":
        cache.get(k, lambda k=k: k.upper())
    assert cache.get("a", lambda: "again") == "again" and cache.get("c", lambda: "no") == "C"


def test_state_words():
    config = {"launch": {"restart": ["actor", "demo_source"], "restart_backoff_max_s": 30, "liveness_grace_s": 60}}
    restartable, window = restart_policy(config)
    assert restartable == {"actor", "demos"} and window == 90
    row = {"role": "actor", "alive": True, "reported_state": "running", "last_seen_age_s": 0.5}
    assert state_word(row, restartable, window) == "running"
    assert state_word({**row, "alive": False, "last_seen_age_s": 5}, restartable, window) == "restarting"
    assert state_word({**row, "alive": False, "last_seen_age_s": 500}, restartable, window) == "gone"
    assert state_word({**row, "role": "learner", "alive": False, "last_seen_age_s": 5}, restartable, window) == "gone"
    finished = {"role": "demos", "alive": False, "reported_state": "stopped", "last_seen_age_s": 900}
    assert state_word(finished, restartable, window) == "finished"
    snap = with_state_words({"roles": [{**finished, "starts": 3}]}, config)
    assert snap["roles"][0]["restarts"] == 2 and snap["roles"][0]["state_word"] == "finished"


def test_png_round_trip():
    rgb = np.random.default_rng(0).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(encode_png(rgb)))), rgb)
    with pytest.raises(ValueError):
        encode_png(np.zeros((4, 4), np.uint8))


def test_projection_matches_the_camera_convention():
    k = np.array([[50.0, 0, 31.5], [0, 50.0, 31.5], [0, 0, 1]])
    cam_to_world = np.eye(4)
    cam_to_world[:3, 3] = [0.0, 0.0, -1.0]  # 1 m behind the origin, looking along +z
    uv, depth = project(np.array([[0.0, 0.0, 0.0], [0.1, -0.2, 0.0]]), k, cam_to_world)
    assert uv.tolist() == [[31.5, 31.5], [36.5, 21.5]] and depth.tolist() == [1.0, 1.0]
    identity_pose = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0]
    pose = project_pose(identity_pose, k, cam_to_world, (64, 64))
    assert pose["in_view"] and pose["uv"] == [31.5, 31.5] and pose["axes"][0] == [34.0, 31.5]
    behind = project_pose([0, 0, -2.0, 0, 0, 0, 1, 1], k, cam_to_world, (64, 64))
    assert not behind["in_view"] and behind["uv"] is None
    assert np.allclose(quaternion_matrix([0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)]) @ [1, 0, 0], [0, 1, 0])


def _observation(step: int, size: int = 8) -> Observation:
    rng = np.random.default_rng(step)
    k = np.array([[10.0, 0, 3.5], [0, 10.0, 3.5], [0, 0, 1]], np.float32)
    e = np.eye(4, dtype=np.float32)
    e[:3, 3] = [0.5, 0.0, 1.0]
    points = (rng.random((size, size, 3)) + [0, 0, 1.5]).astype(np.float32)
    frame = CameraFrame(rng.integers(0, 256, (size, size, 3), dtype=np.uint8), points, k, e)
    return Observation({"front": frame}, np.array([0.4, 0, 0.9, 0, 0, 0, 1], np.float32), 1.0,
                       np.zeros(2, np.float32), np.zeros(7, np.float32), np.zeros(7, np.float32), step=step)


def test_eval_mcap_carries_actions_and_why_it_ended(tmp_path):
    from protocol.episode_file import load_demo, read_episode_view, write_episode_mcap

    observations = [_observation(i) for i in range(3)]
    actions = [np.arange(8, dtype=np.float32) + i for i in range(2)]
    path = tmp_path / "v000003-seed7.mcap"
    write_episode_mcap(path, observations, task="reach_target", seed=7, success=False, actions=actions,
                       end_reason="unreachable", unreachable_reason="planning_failed")
    view = read_episode_view(path)
    assert view.frames == 3 and view.cameras == ["front"] and view.seed == 7
    assert [a.tolist() for a in view.actions] == [a.tolist() for a in actions]
    assert (view.end_reason, view.unreachable_reason) == ("unreachable", "planning_failed")
    assert np.array_equal(view.rgb["front"][2], observations[2].cameras["front"].rgb)
    demo = load_demo(path)  # the demo loader still reads it, and now sees the new fields too
    assert len(demo.observations) == 3 and demo.end_reason == "unreachable" and len(demo.actions) == 2
    with pytest.raises(ValueError):
        write_episode_mcap(tmp_path / "bad.mcap", observations[:1], task="t", seed=0, success=False, actions=actions)


def test_old_eval_files_without_actions_still_read(tmp_path):
    from dashboard.episodes import outcome_of
    from protocol.episode_file import read_episode_view, write_episode_mcap

    path = tmp_path / "v000001-seed1.mcap"
    write_episode_mcap(path, [_observation(0)], task="reach_target", seed=1, success=True)
    view = read_episode_view(path)
    assert view.actions == [] and outcome_of(view) == ("success", "")
