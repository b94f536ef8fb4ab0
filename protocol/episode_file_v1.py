"""The first episode-file layout (``c2farm-demo/1``): read so demos cached before 2026-12-03 and robot
demos (which cannot be re-recorded) keep loading; written only by tests and bench/bench_mcap_writer.py.

Layout: ``/raw/...`` channels of ``application/octet-stream`` without a schema (dtype and shape in
the channel metadata, ``sequence`` = frame index) beside JSON copies of Foxglove's schemas with
base64 images, log times from 0 (1970). Foxglove flags the raw channels; the current layout is in
``protocol.episode_file``.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from protocol.observation import ACTION_SIZE

FORMAT = "c2farm-demo/1"
RAW = "application/octet-stream"
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_NUMS = {"type": "array", "items": {"type": "number"}}
_B64 = {"type": "string", "contentEncoding": "base64"}


def _obj(title: str, props: dict) -> dict:
    return {"title": title, "type": "object", "properties": props}


SCHEMAS: dict[str, dict] = {
    "foxglove.RawImage": _obj("foxglove.RawImage", {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "width": {"type": "integer"},
        "height": {"type": "integer"}, "encoding": {"type": "string"}, "step": {"type": "integer"}, "data": _B64}),
    "foxglove.CameraCalibration": _obj("foxglove.CameraCalibration", {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "width": {"type": "integer"},
        "height": {"type": "integer"}, "distortion_model": {"type": "string"}, "D": _NUMS, "K": _NUMS, "R": _NUMS,
        "P": _NUMS}),
    "foxglove.PointCloud": _obj("foxglove.PointCloud", {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "point_stride": {"type": "integer"},
        "fields": {"type": "array", "items": {"type": "object"}}, "data": _B64}),
    "foxglove.FrameTransforms": _obj("foxglove.FrameTransforms", {"transforms": {"type": "array", "items": _obj(
        "foxglove.FrameTransform", {"timestamp": _TIME, "parent_frame_id": {"type": "string"},
                                    "child_frame_id": {"type": "string"}, "translation": _VEC3, "rotation": _QUAT})}}),
    "c2farm.JointStates": _obj("c2farm.JointStates", {
        "timestamp": _TIME, "name": {"type": "array", "items": {"type": "string"}}, "position": _NUMS,
        "velocity": _NUMS, "gripper_open": {"type": "number"}}),
}


def _stamp(t: int) -> dict:
    return {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}


def _transform(t: int, child: str, m: np.ndarray) -> dict:
    m = np.asarray(m, dtype=float)
    if m.shape == (4, 4):  # the old per-component square roots, kept as they were
        r = m[:3, :3]
        w = np.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
        x = np.copysign(np.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
        y = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
        z = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
        xyz, quat = m[:3, 3], [x, y, z, w]
    else:
        xyz, quat = m[:3], m[3:7]
    return {"timestamp": _stamp(t), "parent_frame_id": "world", "child_frame_id": child,
            "translation": dict(zip("xyz", map(float, xyz))), "rotation": dict(zip("xyzw", map(float, quat)))}


def _point_cloud(t: int, points: np.ndarray, rgb: np.ndarray) -> dict:
    pts, col = points[::2, ::2].reshape(-1, 3).astype(np.float32), rgb[::2, ::2].reshape(-1, 3)
    rec = np.zeros(len(pts), dtype=[("xyz", np.float32, 3), ("rgba", np.uint8, 4)])
    rec["xyz"], rec["rgba"][:, :3], rec["rgba"][:, 3] = pts, col, 255
    fields = [{"name": n, "offset": 4 * i, "type": 7} for i, n in enumerate("xyz")]
    fields += [{"name": n, "offset": 12 + i, "type": 1} for i, n in enumerate(("red", "green", "blue", "alpha"))]
    return {"timestamp": _stamp(t), "frame_id": "world", "point_stride": 16, "fields": fields,
            "pose": {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}},
            "data": base64.b64encode(rec.tobytes()).decode()}


def write_demo_v1(path: str | Path, demo, points_every: int = 5) -> int:
    """``demo`` (an ``episode_file.Demo``) in the old layout, as the writer of before 2026-12-03 did it."""
    from protocol.episode_file import depth_of, episode_metadata, proprio_of

    path = Path(path)
    cams = list(demo.observations[0].cameras) if demo.observations else []
    dt_ns = int(1e9 / demo.control_hz)
    with path.open("wb") as f:
        w = Writer(f, compression=CompressionType.LZ4)
        w.start(profile="", library="c2farm")
        sid = {n: w.register_schema(n, SchemaEncoding.JSONSchema, json.dumps(s).encode()) for n, s in SCHEMAS.items()}

        def raw(topic, dtype, shape):
            return w.register_channel(topic, RAW, 0, metadata={"dtype": dtype, "shape": str(shape)})

        def js(topic, schema):
            return w.register_channel(topic, MessageEncoding.JSON, sid[schema])

        ch = {"proprio": raw("/raw/proprio", "float32", 25), "tf": js("/tf", "foxglove.FrameTransforms"),
              "joints": js("/joint_states", "c2farm.JointStates")}
        if demo.actions:
            ch["action"] = raw("/policy/next_best_pose", "float32", ACTION_SIZE)
        for c in cams:
            size = demo.observations[0].cameras[c].rgb.shape[0]
            ch[c + "rgb"] = raw(f"/raw/{c}/rgb", "uint8", f"{size},{size},3")
            ch[c + "depth"] = raw(f"/raw/{c}/depth", "float32", f"{size},{size}")
            ch[c + "cal"] = raw(f"/raw/{c}/calibration", "float32", 25)
            ch[c + "img"] = js(f"/{c}/image", "foxglove.RawImage")
            ch[c + "info"] = js(f"/{c}/calibration", "foxglove.CameraCalibration")
            ch[c + "pc"] = js(f"/{c}/points", "foxglove.PointCloud")
        for i, o in enumerate(demo.observations):
            t = i * dt_ns

            def put(key, data: bytes):
                w.add_message(ch[key], log_time=t, data=data, publish_time=t, sequence=i)

            put("proprio", proprio_of(o).tobytes())
            if i < len(demo.actions):
                put("action", np.asarray(demo.actions[i], np.float32).reshape(ACTION_SIZE).tobytes())
            tfs = [_transform(t, "grasp", o.gripper_pose)]
            put("joints", json.dumps({"timestamp": _stamp(t), "name": [f"panda_joint{j + 1}" for j in range(7)],
                                      "position": o.joint_positions.tolist(), "velocity": o.joint_velocities.tolist(),
                                      "gripper_open": o.gripper_open}).encode())
            for c in cams:
                fr = o.cameras[c]
                k = fr.intrinsics
                put(c + "rgb", np.ascontiguousarray(fr.rgb).tobytes())
                put(c + "depth", depth_of(fr.points, fr.extrinsics).tobytes())
                put(c + "cal", np.concatenate([k.flatten(), fr.extrinsics.flatten()]).astype(np.float32).tobytes())
                h, wd, _ = fr.rgb.shape
                put(c + "img", json.dumps({"timestamp": _stamp(t), "frame_id": c, "width": wd, "height": h,
                                           "encoding": "rgb8", "step": wd * 3, "data": base64.b64encode(
                                               np.ascontiguousarray(fr.rgb).tobytes()).decode()}).encode())
                kk = [float(v) for v in k.flatten()]
                put(c + "info", json.dumps({"timestamp": _stamp(t), "frame_id": c, "width": h, "height": h,
                                            "distortion_model": "plumb_bob", "D": [0.0] * 5, "K": kk,
                                            "R": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
                                            "P": kk[0:3] + [0.0] + kk[3:6] + [0.0] + kk[6:9] + [0.0]}).encode())
                if i % points_every == 0 or i == len(demo.observations) - 1:
                    put(c + "pc", json.dumps(_point_cloud(t, fr.points, fr.rgb)).encode())
                tfs.append(_transform(t, c, fr.extrinsics))
            put("tf", json.dumps({"transforms": tfs}).encode())
        w.add_metadata("episode", episode_metadata(demo, cams, FORMAT))
        w.finish()
    return path.stat().st_size


def read_arrays_v1(reader, kinds: tuple[str, ...]):
    """(proprio, arrays by (camera, kind), actions), each by frame index, from an old-layout file's raw channels."""
    proprio: dict[int, np.ndarray] = {}
    actions: dict[int, np.ndarray] = {}
    arrays: dict[tuple[str, str], dict[int, np.ndarray]] = {}
    for _, channel, msg in reader.iter_messages():
        topic = channel.topic
        if not topic.startswith("/raw/") and topic != "/policy/next_best_pose":
            continue
        parts = topic.split("/")
        if len(parts) == 4 and parts[3] not in kinds:
            continue
        shape = tuple(int(v) for v in channel.metadata["shape"].split(","))
        arr = np.frombuffer(msg.data, dtype=np.dtype(channel.metadata["dtype"])).reshape(shape)
        if topic == "/raw/proprio":
            proprio[msg.sequence] = arr
        elif topic == "/policy/next_best_pose":
            actions[msg.sequence] = arr
        else:
            arrays.setdefault((parts[2], parts[3]), {})[msg.sequence] = arr
    return proprio, arrays, actions
