"""Episode files as Foxglove reads them: every channel has a schema Foxglove decodes, every message
decodes with the descriptors stored in the file, the exact arrays come back bit for bit, log times
are the recording's wall clock, and files of the first layout still load."""

import time

import numpy as np
import pytest
from mcap.reader import make_reader

from protocol.episode_file import Demo, depth_of, load_demo, proprio_of, read_episode_view, write_episode_mcap
from protocol.episode_file_v1 import write_demo_v1
from protocol.foxglove_schemas import matrix_to_quaternion
from protocol.mcap_protobuf import message_class
from protocol.observation import Observation, camera_frame

#: schema encoding -> the message encoding Foxglove decodes with it
FOXGLOVE_ENCODINGS = {"protobuf": "protobuf", "jsonschema": "json", "ros2msg": "cdr", "flatbuffer": "flatbuffer"}


def _rotation(q) -> np.ndarray:
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _observation(step: int, size: int = 16) -> Observation:
    rng = np.random.default_rng(step)
    k = np.array([[20.0, 0, 7.5], [0, 20.0, 7.5], [0, 0, 1]])
    cams = {}
    for name, q in (("front", [0.0, 0.92, -0.38, 0.0]), ("wrist", [1.0, -3e-8, 2e-9, 1e-7])):  # wrist: looks down
        e = np.eye(4)
        e[:3, :3], e[:3, 3] = _rotation(q), rng.random(3)
        depth = (rng.random((size, size)) + 0.5).astype(np.float32)
        cams[name] = camera_frame(rng.integers(0, 256, (size, size, 3), dtype=np.uint8), depth, k, e)
    f32 = rng.standard_normal(25).astype(np.float32)
    return Observation(cams, f32[:7], float(f32[7]), f32[8:10], f32[10:17], f32[17:24], step=step)


@pytest.fixture(scope="module")
def episode(tmp_path_factory):
    observations = [_observation(i) for i in range(6)]
    actions = [np.random.default_rng(100 + i).standard_normal(8).astype(np.float32) for i in range(5)]
    path = tmp_path_factory.mktemp("eval") / "v000001-seed7.mcap"
    before = time.time_ns()
    write_episode_mcap(path, observations, task="reach_target", seed=7, success=True, actions=actions,
                       end_reason="success")
    return path, observations, actions, before


def _messages(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        return summary, [(s, c, m) for s, c, m in reader.iter_messages()]


def test_every_channel_has_a_schema_foxglove_decodes(episode):
    path, observations, _, before = episode
    summary, messages = _messages(path)
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        assert schema is not None, f"{channel.topic} has no schema"
        assert FOXGLOVE_ENCODINGS.get(schema.encoding) == channel.message_encoding, channel.topic
    names = {s.name for s in summary.schemas.values()}
    assert {"foxglove.RawImage", "foxglove.CameraCalibration", "foxglove.PointCloud", "foxglove.FrameTransforms",
            "foxglove.JointStates", "c2farm.Float32Array"} <= names
    for schema, channel, msg in messages:
        decoded = message_class(schema.name, bytes(schema.data)).FromString(msg.data)
        assert decoded.ByteSize() == len(msg.data), f"{channel.topic}: bytes the descriptor does not name"
    log_times = sorted(m.log_time for _, _, m in messages)
    assert before - 10**9 < log_times[0] <= time.time_ns()  # the recording's wall clock, not 1970
    assert log_times[-1] - log_times[0] == (len(observations) - 1) * 50_000_000  # 20 Hz frames


def test_exact_arrays_round_trip_bit_exactly(episode):
    path, observations, actions, _ = episode
    _, messages = _messages(path)
    by_topic: dict[str, list] = {}
    for schema, channel, msg in messages:
        by_topic.setdefault(channel.topic, []).append(message_class(schema.name, bytes(schema.data)).FromString(
            msg.data))
    bits = np.dtype("<u4")
    for i, o in enumerate(observations):
        assert np.array(by_topic["/raw/proprio"][i].values, np.float32).view(bits).tolist() == \
            proprio_of(o).view(bits).tolist()
        for c, fr in o.cameras.items():
            image, depth = by_topic[f"/{c}/image"][i], by_topic[f"/{c}/depth"][i]
            assert (image.encoding, depth.encoding) == ("rgb8", "32FC1")
            assert image.data == fr.rgb.tobytes() and depth.data == depth_of(fr.points, fr.extrinsics).tobytes()
    assert [np.array(a.values, np.float32).tobytes() for a in by_topic["/policy/next_best_pose"]] == \
        [a.tobytes() for a in actions]

    demo = load_demo(path)
    for a, b in zip(observations, demo.observations, strict=True):
        assert proprio_of(a).tobytes() == proprio_of(b).tobytes()
        for c in a.cameras:
            fa, fb = a.cameras[c], b.cameras[c]
            assert fa.rgb.tobytes() == fb.rgb.tobytes() and fa.intrinsics.tobytes() == fb.intrinsics.tobytes()
            assert fa.extrinsics.tobytes() == fb.extrinsics.tobytes()
            rebuilt = camera_frame(fa.rgb, depth_of(fa.points, fa.extrinsics), fa.intrinsics, fa.extrinsics)
            assert rebuilt.points.tobytes() == fb.points.tobytes()
    assert [a.tobytes() for a in demo.actions] == [a.tobytes() for a in actions]
    view = read_episode_view(path)
    assert view.rgb["wrist"][3].tobytes() == observations[3].cameras["wrist"].rgb.tobytes()
    assert view.extrinsics["front"][0].tobytes() == observations[0].cameras["front"].extrinsics.tobytes()


def test_recording_time_survives_a_rewrite(episode, tmp_path):
    path = episode[0]
    demo = load_demo(path)
    _, messages = _messages(path)
    assert demo.recorded_ns == min(m.log_time for _, _, m in messages)
    write_episode_mcap(tmp_path / "copy.mcap", demo.observations, task=demo.task, seed=demo.seed, success=True)
    again = Demo(**{**demo.__dict__, "recorded_ns": 1_700_000_000_000_000_000})
    from protocol.episode_file import write_demo

    write_demo(tmp_path / "again.mcap", again)
    assert load_demo(tmp_path / "again.mcap").recorded_ns == 1_700_000_000_000_000_000


def test_first_layout_files_still_load(episode, tmp_path):
    path, observations, actions, _ = episode
    old = tmp_path / "old.mcap"
    write_demo_v1(old, load_demo(path))
    demo = load_demo(old)
    assert demo.recorded_ns is None and demo.end_reason == "success"
    assert [a.tobytes() for a in demo.actions] == [a.tobytes() for a in actions]
    for a, b in zip(observations, demo.observations, strict=True):
        assert proprio_of(a).tobytes() == proprio_of(b).tobytes()
        assert a.cameras["wrist"].rgb.tobytes() == b.cameras["wrist"].rgb.tobytes()
    assert read_episode_view(old).frames == len(observations)


@pytest.mark.parametrize("q", [
    [1.0, -3e-8, 2e-9, 1e-7],  # the wrist camera looking straight down
    [1e-9, 1.0, 1e-12, 0.0], [1e-7, 1e-7, 1.0, 1e-7], [0.5, 0.5, 0.5, 0.5], [0.0, 0.92, -0.38, 0.0],
    [0.7071067811865476, 0.0, 0.0, 0.7071067811865476], [2e-8, 0.0, 0.0, 1.0], [0.3, -1e-10, 0.0, -0.9],
])
def test_quaternion_from_rotation_is_exact_near_zero_components(q):
    q = np.asarray(q) / np.linalg.norm(q)
    q = -q if q[3] < 0 else q
    got = matrix_to_quaternion(_rotation(q))
    assert np.abs(got - q).max() < 1e-9 or (q[3] == 0 and np.abs(got + q).max() < 1e-9)
    assert np.abs(_rotation(got) - _rotation(q)).max() < 1e-9


def test_the_files_camera_transform_matches_the_stored_extrinsics(episode):
    path, observations, _, _ = episode
    summary, messages = _messages(path)
    tf = next(message_class(s.name, bytes(s.data)).FromString(m.data) for s, c, m in messages if c.topic == "/tf")
    wrist = next(t for t in tf.transforms if t.child_frame_id == "wrist")
    r = wrist.rotation
    stored = observations[0].cameras["wrist"].extrinsics.astype(np.float64)
    assert np.abs(_rotation([r.x, r.y, r.z, r.w]) - stored[:3, :3]).max() < 1e-6  # float32 storage, not the method


def test_a_newer_layout_is_refused_naming_its_format(tmp_path):
    from mcap.writer import Writer

    from protocol.episode_file import DemoFileError

    path = tmp_path / "future.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("episode", {"task": "t", "frames": "0", "cameras": "[]", "format": "c2farm-demo/9"})
        w.finish()
    with pytest.raises(DemoFileError, match="c2farm-demo/9"):
        load_demo(path)
