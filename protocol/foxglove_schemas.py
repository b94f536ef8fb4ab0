"""Foxglove messages for episode files, built with foxglove-sdk so Foxglove decodes every channel.

The SDK writes its well-known schemas (RawImage, CameraCalibration, PointCloud, FrameTransforms,
JointStates) protobuf-encoded with their descriptors in the file. The exact arrays that are no
Foxglove message (proprioception, camera matrices, next-best poses) use one small protobuf schema
of our own, ``c2farm.Float32Array``, whose FileDescriptorSet is stored the same way, so Foxglove
decodes (and plots) them too instead of flagging a schemaless channel.
"""

from __future__ import annotations

import numpy as np
from foxglove import messages as m
from google.protobuf import descriptor_pb2

ARRAY_SCHEMA = "c2farm.Float32Array"
_F = descriptor_pb2.FieldDescriptorProto


def _array_descriptor() -> bytes:
    """FileDescriptorSet of ``message Float32Array { repeated float values = 1; }`` (proto3: packed)."""
    fds = descriptor_pb2.FileDescriptorSet()
    f = fds.file.add(name="c2farm/float32_array.proto", package="c2farm", syntax="proto3")
    f.message_type.add(name="Float32Array").field.add(name="values", number=1, type=_F.TYPE_FLOAT,
                                                      label=_F.LABEL_REPEATED)
    return fds.SerializeToString()


ARRAY_DESCRIPTOR = _array_descriptor()


def _varint(n: int) -> bytes:
    out = bytearray()
    while n > 0x7F:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def float32_array(values: np.ndarray) -> bytes:
    """A ``c2farm.Float32Array`` message: field 1, packed little-endian float32, bit-exact (NaNs too)."""
    payload = np.ascontiguousarray(values, dtype="<f4").tobytes()
    return b"\x0a" + _varint(len(payload)) + payload


def stamp(t_ns: int) -> m.Timestamp:
    return m.Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)


def raw_image(t_ns: int, frame_id: str, image: np.ndarray) -> m.RawImage:
    """``rgb8`` for uint8 [H, W, 3], ``32FC1`` for float32 [H, W] (depth): the array's exact bytes."""
    image = np.ascontiguousarray(image)
    h, w = image.shape[:2]
    encoding = "rgb8" if image.dtype == np.uint8 else "32FC1"
    return m.RawImage(timestamp=stamp(t_ns), frame_id=frame_id, width=w, height=h, encoding=encoding,
                      step=image.strides[0], data=image.astype(image.dtype.newbyteorder("<"), copy=False).tobytes())


def camera_calibration(t_ns: int, frame_id: str, k: np.ndarray, size: int) -> m.CameraCalibration:
    kk = [float(v) for v in np.asarray(k).flatten()]
    return m.CameraCalibration(timestamp=stamp(t_ns), frame_id=frame_id, width=size, height=size,
                               distortion_model="plumb_bob", D=[0.0] * 5, K=kk, R=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
                               P=kk[0:3] + [0.0] + kk[3:6] + [0.0] + kk[6:9] + [0.0])


def point_cloud(t_ns: int, points: np.ndarray, rgb: np.ndarray, stride: int = 2) -> m.PointCloud:
    """World-frame coloured cloud, every ``stride``-th pixel (a cheap preview)."""
    pts = points[::stride, ::stride].reshape(-1, 3).astype(np.float32)
    col = rgb[::stride, ::stride].reshape(-1, 3)
    rec = np.zeros(len(pts), dtype=[("xyz", "<f4", 3), ("rgba", np.uint8, 4)])
    rec["xyz"], rec["rgba"][:, :3], rec["rgba"][:, 3] = pts, col, 255
    f32, u8 = m.PackedElementFieldNumericType.Float32, m.PackedElementFieldNumericType.Uint8
    fields = [m.PackedElementField(name=n, offset=4 * i, type=f32) for i, n in enumerate("xyz")]
    fields += [m.PackedElementField(name=n, offset=12 + i, type=u8) for i, n in enumerate(("red", "green", "blue",
                                                                                           "alpha"))]
    return m.PointCloud(timestamp=stamp(t_ns), frame_id="world",
                        pose=m.Pose(position=m.Vector3(x=0, y=0, z=0), orientation=m.Quaternion(x=0, y=0, z=0, w=1)),
                        point_stride=16, fields=fields, data=rec.tobytes())


def transform(t_ns: int, child: str, matrix_or_pose) -> m.FrameTransform:
    """world -> child from a 4x4 matrix or a 7-vector (xyz + quat xyzw)."""
    a = np.asarray(matrix_or_pose, dtype=np.float64)
    if a.shape == (4, 4):
        xyz, quat = a[:3, 3], matrix_to_quaternion(a[:3, :3])
    else:
        xyz, quat = a[:3], a[3:7]
    return m.FrameTransform(timestamp=stamp(t_ns), parent_frame_id="world", child_frame_id=child,
                            translation=m.Vector3(**dict(zip("xyz", map(float, xyz)))),
                            rotation=m.Quaternion(**dict(zip("xyzw", map(float, quat)))))


def joint_states(t_ns: int, positions: np.ndarray, velocities: np.ndarray, fingers: np.ndarray) -> m.JointStates:
    """The arm's 7 joints (position, velocity) and the two finger joints (position)."""
    arm = [m.JointState(name=f"panda_joint{j + 1}", position=float(p), velocity=float(v))
           for j, (p, v) in enumerate(zip(positions, velocities))]
    hand = [m.JointState(name=f"panda_finger_joint{j + 1}", position=float(p)) for j, p in enumerate(fingers)]
    return m.JointStates(timestamp=stamp(t_ns), joints=arm + hand)


def matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w; w >= 0) of a rotation matrix, by Shepperd's method.

    The square root is taken of the largest of 1 + trace and the three 1 + 2 r_ii - trace, and
    the other components come from off-diagonal sums and differences divided by it; taking the
    root of a near-zero term instead (one sqrt per component) is off by ~sqrt(eps) near zero
    components (7.8e-4 on the wrist camera).
    """
    r = np.asarray(r, dtype=np.float64)
    t = r[0, 0] + r[1, 1] + r[2, 2]
    k = int(np.argmax([t, r[0, 0], r[1, 1], r[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + 2 * r[0, 0] - t)
        q = [s / 4, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + 2 * r[1, 1] - t)
        q = [(r[0, 1] + r[1, 0]) / s, s / 4, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + 2 * r[2, 2] - t)
        q = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, s / 4, (r[1, 0] - r[0, 1]) / s]
    quat = np.array(q) / np.linalg.norm(q)
    return -quat if quat[3] < 0 else quat
