"""Foxglove well-known JSON schemas (mcap ships none) and message builders, so demo files open in Foxglove.

Written from the field lists of foxglove-sdk's ``schemas/jsonschema``: schema names must be exactly
``foxglove.X`` with ``jsonschema`` encoding and ``json`` messages; bytes fields are base64 strings.
"""

from __future__ import annotations

import base64

import numpy as np

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_NUMS = {"type": "array", "items": {"type": "number"}}


def _obj(title: str, props: dict) -> dict:
    return {"title": title, "type": "object", "properties": props}


_FRAME_TRANSFORM = _obj("foxglove.FrameTransform", {
    "timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
    "translation": _VEC3, "rotation": _QUAT})

SCHEMAS: dict[str, dict] = {
    "foxglove.RawImage": _obj("foxglove.RawImage", {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "width": {"type": "integer"},
        "height": {"type": "integer"}, "encoding": {"type": "string"}, "step": {"type": "integer"},
        "data": {"type": "string", "contentEncoding": "base64"}}),
    "foxglove.CameraCalibration": _obj("foxglove.CameraCalibration", {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "width": {"type": "integer"},
        "height": {"type": "integer"}, "distortion_model": {"type": "string"}, "D": _NUMS, "K": _NUMS, "R": _NUMS,
        "P": _NUMS}),
    "foxglove.PointCloud": _obj("foxglove.PointCloud", {
        "timestamp": _TIME, "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}},
        "point_stride": {"type": "integer"},
        "fields": {"type": "array", "items": _obj("foxglove.PackedElementField", {
            "name": {"type": "string"}, "offset": {"type": "integer"}, "type": {"type": "integer"}})},
        "data": {"type": "string", "contentEncoding": "base64"}}),
    "foxglove.FrameTransforms": _obj("foxglove.FrameTransforms", {
        "transforms": {"type": "array", "items": _FRAME_TRANSFORM}}),
    # Foxglove has no well-known joint-state schema; this plain one plots fine in its Plot panel.
    "c2farm.JointStates": _obj("c2farm.JointStates", {
        "timestamp": _TIME, "name": {"type": "array", "items": {"type": "string"}}, "position": _NUMS,
        "velocity": _NUMS, "gripper_open": {"type": "number"}}),
}
FLOAT32, UINT8 = 7, 1


def stamp(t_ns: int) -> dict:
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def raw_image(t_ns: int, frame_id: str, rgb: np.ndarray) -> dict:
    h, w, _ = rgb.shape
    return {"timestamp": stamp(t_ns), "frame_id": frame_id, "width": w, "height": h, "encoding": "rgb8",
            "step": w * 3, "data": base64.b64encode(np.ascontiguousarray(rgb).tobytes()).decode()}


def camera_calibration(t_ns: int, frame_id: str, k: np.ndarray, size: int) -> dict:
    kk = [float(v) for v in k.flatten()]
    return {"timestamp": stamp(t_ns), "frame_id": frame_id, "width": size, "height": size,
            "distortion_model": "plumb_bob", "D": [0.0] * 5, "K": kk, "R": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
            "P": kk[0:3] + [0.0] + kk[3:6] + [0.0] + kk[6:9] + [0.0]}


def point_cloud(t_ns: int, points: np.ndarray, rgb: np.ndarray, stride: int = 2) -> dict:
    """World-frame coloured cloud, every ``stride``-th pixel (a cheap preview)."""
    pts = points[::stride, ::stride].reshape(-1, 3).astype(np.float32)
    col = rgb[::stride, ::stride].reshape(-1, 3)
    rec = np.zeros(len(pts), dtype=[("xyz", np.float32, 3), ("rgba", np.uint8, 4)])
    rec["xyz"], rec["rgba"][:, :3], rec["rgba"][:, 3] = pts, col, 255
    fields = [{"name": n, "offset": 4 * i, "type": FLOAT32} for i, n in enumerate("xyz")]
    fields += [{"name": n, "offset": 12 + i, "type": UINT8} for i, n in enumerate(("red", "green", "blue", "alpha"))]
    return {"timestamp": stamp(t_ns), "frame_id": "world",
            "pose": {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}},
            "point_stride": 16, "fields": fields, "data": base64.b64encode(rec.tobytes()).decode()}


def transform(t_ns: int, child: str, matrix_or_pose) -> dict:
    """world -> child from a 4x4 matrix or a 7-vector (xyz + quat xyzw)."""
    m = np.asarray(matrix_or_pose, dtype=float)
    if m.shape == (4, 4):
        xyz, quat = m[:3, 3], _matrix_to_quaternion(m[:3, :3])
    else:
        xyz, quat = m[:3], m[3:7]
    return {"timestamp": stamp(t_ns), "parent_frame_id": "world", "child_frame_id": child,
            "translation": dict(zip("xyz", map(float, xyz))), "rotation": dict(zip("xyzw", map(float, quat)))}


def _matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    w = np.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return np.array([x, y, z, w])
