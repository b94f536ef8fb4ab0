"""Demo files: one MCAP per episode. Raw channels (lz4 chunks) reload observations; Foxglove JSON
channels (images, calibration, point clouds, transforms, joint states) make the file viewable.

Raw layout, one message per control step per channel, ``sequence`` = frame index:
``/raw/proprio`` float32[25] = gripper_pose 7, gripper_open, fingers 2, joints 7, velocities 7, step;
``/raw/<cam>/rgb`` uint8 [H,W,3]; ``/raw/<cam>/depth`` float32 [H,W] z-depth;
``/raw/<cam>/calibration`` float32 K(9) + extrinsics(16). Points are re-derived from depth with the
stored matrices, as the environment derived them. Episode facts are in the ``episode`` metadata.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from actors.demos import foxglove as fx
from actors.sim.cameras import camera_frame
from protocol.observation import Observation

PROPRIO_SIZE = 25
RAW = "application/octet-stream"


class DemoFileError(ValueError):
    """A demo file that cannot be read; names the file and says why."""

    def __init__(self, path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = str(path), reason


@dataclass
class Demo:
    """One scripted demonstration episode."""

    task: str
    seed: int
    success: bool
    observations: list[Observation]
    waypoint_frames: list[int] = field(default_factory=list)  #: frame index at which each scripted waypoint ended
    control_hz: int = 20  #: recording rate (frames per simulated second)
    attempts: int = 1  #: seeds tried for this demo (failed demos are retried with the next seed)


def _proprio(o: Observation) -> np.ndarray:
    return np.concatenate([o.gripper_pose, [o.gripper_open], o.finger_positions, o.joint_positions,
                           o.joint_velocities, [o.step]]).astype(np.float32)


def _depth(points: np.ndarray, extrinsics: np.ndarray) -> np.ndarray:
    """Optical-axis depth of a world-frame organised cloud."""
    e = extrinsics.astype(np.float64)
    return ((points.astype(np.float64) - e[:3, 3]) @ e[:3, 2]).astype(np.float32)


def write_demo(path: str | Path, demo: Demo, points_every: int = 5) -> int:
    """Write ``demo``; returns the file size in bytes. Point-cloud previews every ``points_every`` frames."""
    path = Path(path)
    cams = list(demo.observations[0].cameras) if demo.observations else []
    dt_ns = int(1e9 / demo.control_hz)
    with path.open("wb") as f:
        w = Writer(f, compression=CompressionType.LZ4)
        w.start(profile="", library="c2farm")
        sid = {n: w.register_schema(n, SchemaEncoding.JSONSchema, json.dumps(s).encode()) for n, s in fx.SCHEMAS.items()}

        def raw(topic, meta):
            return w.register_channel(topic, RAW, 0, metadata={k: str(v) for k, v in meta.items()})

        def js(topic, schema):
            return w.register_channel(topic, MessageEncoding.JSON, sid[schema])

        ch = {"proprio": raw("/raw/proprio", {"dtype": "float32", "shape": PROPRIO_SIZE}),
              "tf": js("/tf", "foxglove.FrameTransforms"), "joints": js("/joint_states", "c2farm.JointStates")}
        for c in cams:
            size = demo.observations[0].cameras[c].rgb.shape[0]
            ch[c + "rgb"] = raw(f"/raw/{c}/rgb", {"dtype": "uint8", "shape": f"{size},{size},3"})
            ch[c + "depth"] = raw(f"/raw/{c}/depth", {"dtype": "float32", "shape": f"{size},{size}"})
            ch[c + "cal"] = raw(f"/raw/{c}/calibration", {"dtype": "float32", "shape": 25})
            ch[c + "img"] = js(f"/{c}/image", "foxglove.RawImage")
            ch[c + "info"] = js(f"/{c}/calibration", "foxglove.CameraCalibration")
            ch[c + "pc"] = js(f"/{c}/points", "foxglove.PointCloud")
        for i, o in enumerate(demo.observations):
            t = i * dt_ns

            def put(key, data: bytes):
                w.add_message(ch[key], log_time=t, data=data, publish_time=t, sequence=i)

            put("proprio", _proprio(o).tobytes())
            tfs = [fx.transform(t, "grasp", o.gripper_pose)]
            put("joints", json.dumps({"timestamp": fx.stamp(t), "name": [f"panda_joint{j + 1}" for j in range(7)],
                                      "position": o.joint_positions.tolist(), "velocity": o.joint_velocities.tolist(),
                                      "gripper_open": o.gripper_open}).encode())
            for c in cams:
                fr = o.cameras[c]
                put(c + "rgb", np.ascontiguousarray(fr.rgb).tobytes())
                put(c + "depth", _depth(fr.points, fr.extrinsics).tobytes())
                put(c + "cal", np.concatenate([fr.intrinsics.flatten(), fr.extrinsics.flatten()]).astype(np.float32).tobytes())
                put(c + "img", json.dumps(fx.raw_image(t, c, fr.rgb)).encode())
                put(c + "info", json.dumps(fx.camera_calibration(t, c, fr.intrinsics, fr.rgb.shape[0])).encode())
                if i % points_every == 0 or i == len(demo.observations) - 1:
                    put(c + "pc", json.dumps(fx.point_cloud(t, fr.points, fr.rgb)).encode())
                tfs.append(fx.transform(t, c, fr.extrinsics))
            put("tf", json.dumps({"transforms": tfs}).encode())
        w.add_metadata("episode", {
            "task": demo.task, "seed": str(demo.seed), "success": json.dumps(demo.success),
            "frames": str(len(demo.observations)), "cameras": json.dumps(cams),
            "waypoint_frames": json.dumps(demo.waypoint_frames), "control_hz": str(demo.control_hz),
            "attempts": str(demo.attempts), "format": "c2farm-demo/1"})
        w.finish()
    return path.stat().st_size


def load_demo(path: str | Path) -> Demo:
    """Read a demo file back into Observations; any problem raises DemoFileError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise DemoFileError(path, "no such file")
    try:
        with path.open("rb") as f:
            reader = make_reader(f)
            meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
            if "episode" not in meta:
                raise DemoFileError(path, "no 'episode' metadata: not a c2farm demo file")
            ep = meta["episode"]
            n, cams = int(ep["frames"]), json.loads(ep["cameras"])
            proprio: dict[int, np.ndarray] = {}
            arrays: dict[tuple[str, str], dict[int, np.ndarray]] = {}
            for _, channel, msg in reader.iter_messages():
                topic = channel.topic
                if not topic.startswith("/raw/"):
                    continue
                dtype = np.dtype(channel.metadata["dtype"])
                shape = tuple(int(v) for v in channel.metadata["shape"].split(","))
                arr = np.frombuffer(msg.data, dtype=dtype).reshape(shape)
                if topic == "/raw/proprio":
                    proprio[msg.sequence] = arr
                else:
                    _, _, cam, kind = topic.split("/")
                    arrays.setdefault((cam, kind), {})[msg.sequence] = arr
    except DemoFileError:
        raise
    except Exception as e:  # truncated, corrupt, not MCAP at all ...
        raise DemoFileError(path, f"malformed or truncated MCAP ({type(e).__name__}: {e})") from None
    if sorted(proprio) != list(range(n)) or any(
            sorted(arrays.get((c, k), {})) != list(range(n)) for c in cams for k in ("rgb", "depth", "calibration")):
        raise DemoFileError(path, f"expected {n} complete frames, found {len(proprio)}: file is truncated or inconsistent")
    observations = []
    for i in range(n):
        v = proprio[i]
        frames = {}
        for c in cams:
            cal = arrays[(c, "calibration")][i]
            frames[c] = camera_frame(arrays[(c, "rgb")][i].copy(), arrays[(c, "depth")][i],
                                     cal[:9].reshape(3, 3), cal[9:].reshape(4, 4))
        observations.append(Observation(
            cameras=frames, gripper_pose=v[0:7].copy(), gripper_open=float(v[7]), finger_positions=v[8:10].copy(),
            joint_positions=v[10:17].copy(), joint_velocities=v[17:24].copy(), step=int(v[24])))
    return Demo(task=ep["task"], seed=int(ep["seed"]), success=json.loads(ep["success"]), observations=observations,
                waypoint_frames=json.loads(ep["waypoint_frames"]), control_hz=int(ep["control_hz"]),
                attempts=int(ep["attempts"]))


def write_episode_mcap(path: str | Path, observations: list[Observation], task: str, seed: int, success: bool,
                       control_hz: int = 20) -> int:
    """Any episode (e.g. an evaluation rollout, one frame per decision) as a demo-format MCAP file."""
    return write_demo(path, Demo(task=task, seed=seed, success=success, observations=list(observations),
                                 control_hz=control_hz))
