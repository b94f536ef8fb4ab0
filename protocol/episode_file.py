"""Demo files: one MCAP per episode. Raw channels (lz4 chunks) reload observations; Foxglove JSON
channels (images, calibration, point clouds, transforms, joint states) make the file viewable.

Raw layout, one message per control step per channel, ``sequence`` = frame index:
``/raw/proprio`` float32[25] = gripper_pose 7, gripper_open, fingers 2, joints 7, velocities 7, step;
``/raw/<cam>/rgb`` uint8 [H,W,3]; ``/raw/<cam>/depth`` float32 [H,W] z-depth;
``/raw/<cam>/calibration`` float32 K(9) + extrinsics(16). Points are re-derived from depth with the
stored matrices, as the environment derived them. Episode facts are in the ``episode`` metadata.

Policy episodes (evaluation rollouts) also carry ``/policy/next_best_pose`` float32[8] (xyz, quat
xyzw, gripper open), ``sequence`` = the frame it was chosen from (one fewer than the frames), and
say why they ended in the metadata (``end``: success / timeout / unreachable / failed, plus
``unreachable_reason``). Both are additions: files without them still load, and readers that
predate them skip the channel (it is outside ``/raw/``).

Robot demos also carry the operator's ``keyframes`` (JSON frame indices) in the metadata; files
without them (every simulated demo, robot demos recorded before) have their keyframes discovered.

:func:`read_episode_view` reads only what a viewer needs (images, calibration, poses, actions),
without the points and without the simulator, so the dashboard can use it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from protocol import foxglove_schemas as fx
from protocol.observation import ACTION_SIZE, Observation, camera_frame

PROPRIO_SIZE = 25
RAW = "application/octet-stream"
ACTION_TOPIC = "/policy/next_best_pose"


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
    keyframes: list[int] | None = None  #: the operator's keyframes (robot demos); None: discover them
    #: the depth-0 box it was recorded for (robot demos); None: the task's
    scene_bounds: tuple[float, ...] | None = None
    control_hz: int = 20  #: recording rate (frames per simulated second)
    attempts: int = 1  #: seeds tried for this demo (failed demos are retried with the next seed)
    #: policy episodes: the pose chosen at each frame but the last
    actions: list[np.ndarray] = field(default_factory=list)
    end_reason: str = ""  #: policy episodes: why it ended (success, timeout, unreachable, failed); "" for demos
    unreachable_reason: str = ""  #: the control agent's why, for an unreachable end


def _proprio(o: Observation) -> np.ndarray:
    return np.concatenate([o.gripper_pose, [o.gripper_open], o.finger_positions, o.joint_positions,
                           o.joint_velocities, [o.step]]).astype(np.float32)


def _depth(points: np.ndarray, extrinsics: np.ndarray) -> np.ndarray:
    """Optical-axis depth of a world-frame organised cloud."""
    e = extrinsics.astype(np.float64)
    return ((points.astype(np.float64) - e[:3, 3]) @ e[:3, 2]).astype(np.float32)


def keyframes_problem(keyframes: object, frames: int) -> str:
    """Why ``keyframes`` are no demo's keyframes (increasing frame indices after frame 0), or ""."""
    if not isinstance(keyframes, list) or not all(type(k) is int for k in keyframes):
        return f"keyframes {keyframes!r} are not a list of frame indices"
    if any(not 0 < k < frames for k in keyframes) or keyframes != sorted(set(keyframes)):
        return f"keyframes {keyframes} are not increasing frames in 1..{frames - 1}"
    return ""


def write_demo(path: str | Path, demo: Demo, points_every: int = 5) -> int:
    """Write ``demo``; returns the file size in bytes. Point-cloud previews every ``points_every`` frames."""
    path = Path(path)
    if demo.keyframes is not None and (problem := keyframes_problem(demo.keyframes, len(demo.observations))):
        raise ValueError(problem)
    cams = list(demo.observations[0].cameras) if demo.observations else []
    dt_ns = int(1e9 / demo.control_hz)
    with path.open("wb") as f:
        w = Writer(f, compression=CompressionType.LZ4)
        w.start(profile="", library="c2farm")
        sid = {
            n: w.register_schema(n, SchemaEncoding.JSONSchema, json.dumps(s).encode()) for n, s in fx.SCHEMAS.items()
        }

        def raw(topic, meta):
            return w.register_channel(topic, RAW, 0, metadata={k: str(v) for k, v in meta.items()})

        def js(topic, schema):
            return w.register_channel(topic, MessageEncoding.JSON, sid[schema])

        ch = {"proprio": raw("/raw/proprio", {"dtype": "float32", "shape": PROPRIO_SIZE}),
              "tf": js("/tf", "foxglove.FrameTransforms"), "joints": js("/joint_states", "c2farm.JointStates")}
        if demo.actions:
            ch["action"] = raw(ACTION_TOPIC, {"dtype": "float32", "shape": ACTION_SIZE})
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
            if i < len(demo.actions):
                put("action", np.asarray(demo.actions[i], np.float32).reshape(ACTION_SIZE).tobytes())
            tfs = [fx.transform(t, "grasp", o.gripper_pose)]
            put("joints", json.dumps({"timestamp": fx.stamp(t), "name": [f"panda_joint{j + 1}" for j in range(7)],
                                      "position": o.joint_positions.tolist(), "velocity": o.joint_velocities.tolist(),
                                      "gripper_open": o.gripper_open}).encode())
            for c in cams:
                fr = o.cameras[c]
                put(c + "rgb", np.ascontiguousarray(fr.rgb).tobytes())
                put(c + "depth", _depth(fr.points, fr.extrinsics).tobytes())
                put(
                    c + "cal",
                    np.concatenate([fr.intrinsics.flatten(), fr.extrinsics.flatten()]).astype(np.float32).tobytes(),
                )
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
            "attempts": str(demo.attempts), "format": "c2farm-demo/1",
            **({"keyframes": json.dumps(demo.keyframes)} if demo.keyframes is not None else {}),
            **({"scene_bounds": json.dumps([float(b) for b in demo.scene_bounds])} if demo.scene_bounds else {}),
            **({"end": demo.end_reason, "unreachable_reason": demo.unreachable_reason} if demo.end_reason else {})})
        w.finish()
    return path.stat().st_size


@dataclass
class _RawEpisode:
    """The ``/raw/`` and policy channels of one file, by frame index, plus its ``episode`` metadata."""

    meta: dict[str, str]
    frames: int
    cameras: list[str]
    proprio: dict[int, np.ndarray]
    arrays: dict[tuple[str, str], dict[int, np.ndarray]]
    actions: dict[int, np.ndarray]


def _read_raw(path: Path, kinds: tuple[str, ...]) -> _RawEpisode:
    """Read the file's raw channels of ``kinds`` (rgb, depth, calibration); DemoFileError on any problem."""
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
            actions: dict[int, np.ndarray] = {}
            arrays: dict[tuple[str, str], dict[int, np.ndarray]] = {}
            for _, channel, msg in reader.iter_messages():
                topic = channel.topic
                if not topic.startswith("/raw/") and topic != ACTION_TOPIC:
                    continue
                parts = topic.split("/")
                if len(parts) == 4 and parts[3] not in kinds:
                    continue
                dtype = np.dtype(channel.metadata["dtype"])
                shape = tuple(int(v) for v in channel.metadata["shape"].split(","))
                arr = np.frombuffer(msg.data, dtype=dtype).reshape(shape)
                if topic == "/raw/proprio":
                    proprio[msg.sequence] = arr
                elif topic == ACTION_TOPIC:
                    actions[msg.sequence] = arr
                else:
                    _, _, cam, kind = parts
                    arrays.setdefault((cam, kind), {})[msg.sequence] = arr
    except DemoFileError:
        raise
    except Exception as e:  # truncated, corrupt, not MCAP at all ...
        raise DemoFileError(path, f"malformed or truncated MCAP ({type(e).__name__}: {e})") from None
    if sorted(proprio) != list(range(n)) or any(
            sorted(arrays.get((c, k), {})) != list(range(n)) for c in cams for k in kinds):
        raise DemoFileError(
            path, f"expected {n} complete frames, found {len(proprio)}: file is truncated or inconsistent"
        )
    if actions and sorted(actions) != list(range(len(actions))):
        raise DemoFileError(path, f"next-best poses of frames {sorted(actions)} are not one per frame from 0")
    return _RawEpisode(ep, n, cams, proprio, arrays, actions)


def load_demo(path: str | Path) -> Demo:
    """Read a demo file back into Observations; any problem raises DemoFileError naming the file."""
    path = Path(path)
    raw = _read_raw(path, ("rgb", "depth", "calibration"))
    ep, arrays = raw.meta, raw.arrays
    observations = []
    for i in range(raw.frames):
        v = raw.proprio[i]
        frames = {}
        for c in raw.cameras:
            cal = arrays[(c, "calibration")][i]
            frames[c] = camera_frame(arrays[(c, "rgb")][i].copy(), arrays[(c, "depth")][i],
                                     cal[:9].reshape(3, 3), cal[9:].reshape(4, 4))
        observations.append(Observation(
            cameras=frames, gripper_pose=v[0:7].copy(), gripper_open=float(v[7]), finger_positions=v[8:10].copy(),
            joint_positions=v[10:17].copy(), joint_velocities=v[17:24].copy(), step=int(v[24])))
    return Demo(task=ep["task"], seed=int(ep["seed"]), success=json.loads(ep["success"]), observations=observations,
                waypoint_frames=json.loads(ep["waypoint_frames"]), keyframes=_read_keyframes(path, raw),
                scene_bounds=_read_scene_bounds(path, ep),
                control_hz=int(ep["control_hz"]),
                attempts=int(ep["attempts"]), actions=[raw.actions[i].copy() for i in sorted(raw.actions)],
                end_reason=ep.get("end", ""), unreachable_reason=ep.get("unreachable_reason", ""))


def _read_scene_bounds(path: Path, meta: dict) -> tuple[float, ...] | None:
    """The depth-0 box a robot demo was recorded for; None for a file without one."""
    if "scene_bounds" not in meta:
        return None
    try:
        bounds = tuple(float(b) for b in json.loads(meta["scene_bounds"]))
    except (ValueError, TypeError):
        raise DemoFileError(path, f"scene_bounds {meta['scene_bounds']!r} are not 6 numbers") from None
    if len(bounds) != 6 or not all(np.isfinite(bounds)) or any(lo >= hi for lo, hi in zip(bounds[:3], bounds[3:])):
        raise DemoFileError(path, f"scene_bounds {list(bounds)} are no box (min xyz, max xyz)")
    return bounds


def _read_keyframes(path: Path, raw: _RawEpisode) -> list[int] | None:
    """The operator's keyframes from the metadata; None for a file without them."""
    if "keyframes" not in raw.meta:
        return None
    try:
        keyframes = json.loads(raw.meta["keyframes"])
    except ValueError:
        raise DemoFileError(path, f"keyframes {raw.meta['keyframes']!r} are not JSON") from None
    if problem := keyframes_problem(keyframes, raw.frames):
        raise DemoFileError(path, problem)
    return keyframes


@dataclass
class EpisodeView:
    """What a viewer shows of an episode file: images, camera matrices, poses; no points."""

    task: str
    seed: int
    success: bool
    cameras: list[str]
    rgb: dict[str, list[np.ndarray]]  #: per camera, uint8 [H, W, 3] per frame
    intrinsics: dict[str, list[np.ndarray]]  #: per camera, float32 [3, 3] per frame
    extrinsics: dict[str, list[np.ndarray]]  #: per camera, float32 [4, 4] camera-to-world per frame
    gripper_pose: list[np.ndarray]  #: float32 [7] per frame
    actions: list[np.ndarray]  #: float32 [8] per decision (empty for files written without them)
    end_reason: str  #: success, timeout, unreachable, failed; "" when the file does not say
    unreachable_reason: str

    @property
    def frames(self) -> int:
        return len(self.gripper_pose)


def read_episode_view(path: str | Path) -> EpisodeView:
    """The viewable part of an episode file (no points, no simulator import); DemoFileError on any problem."""
    path = Path(path)
    raw = _read_raw(path, ("rgb", "calibration"))
    ep, order = raw.meta, range(raw.frames)
    cal = {c: [raw.arrays[(c, "calibration")][i] for i in order] for c in raw.cameras}
    return EpisodeView(
        task=ep["task"], seed=int(ep["seed"]), success=json.loads(ep["success"]), cameras=list(raw.cameras),
        rgb={c: [raw.arrays[(c, "rgb")][i] for i in order] for c in raw.cameras},
        intrinsics={c: [k[:9].reshape(3, 3) for k in cal[c]] for c in raw.cameras},
        extrinsics={c: [k[9:].reshape(4, 4) for k in cal[c]] for c in raw.cameras},
        gripper_pose=[raw.proprio[i][0:7] for i in order],
        actions=[raw.actions[i] for i in sorted(raw.actions)],
        end_reason=ep.get("end", ""), unreachable_reason=ep.get("unreachable_reason", ""))


def write_episode_mcap(path: str | Path, observations: list[Observation], task: str, seed: int, success: bool,
                       control_hz: int = 20, actions=(), end_reason: str = "", unreachable_reason: str = "") -> int:
    """Any episode (e.g. an evaluation rollout, one frame per decision) as a demo-format MCAP file.

    ``actions`` are the next-best poses executed from each frame but the last; ``end_reason``
    (success, timeout, unreachable, failed) and ``unreachable_reason`` say why it ended.
    """
    if len(actions) > max(0, len(observations) - 1):
        raise ValueError(f"{len(actions)} actions for {len(observations)} frames: at most one per frame but the last")
    return write_demo(path, Demo(task=task, seed=seed, success=success, observations=list(observations),
                                 control_hz=control_hz, actions=[np.asarray(a, np.float32) for a in actions],
                                 end_reason=end_reason, unreachable_reason=unreachable_reason))
