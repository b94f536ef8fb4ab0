"""Episode files: one MCAP per demo or evaluation episode, written with foxglove-sdk so it opens in
Foxglove with every channel decoded, and read back here bit-exactly into Observations.

Layout (``c2farm-demo/2``, logged by ``protocol.episode_channels``, as the live view logs it), one
message per frame per channel, in frame order; log times are the wall-clock time of recording
(frame i at ``recorded_ns + i / control_hz``):

- ``/<cam>/image`` foxglove.RawImage ``rgb8`` and ``/<cam>/depth`` foxglove.RawImage ``32FC1``
  (optical-axis depth, metres): the exact uint8 / float32 arrays, viewable as they are;
- ``/raw/proprio`` float32[25] = gripper_pose 7, gripper_open, fingers 2, joints 7, velocities 7,
  step; ``/raw/<cam>/calibration`` float32 K(9) + extrinsics(16); policy episodes also
  ``/policy/next_best_pose`` float32[8] (xyz, quat xyzw, gripper open), one per frame but the last:
  the ``c2farm.Float32Array`` protobuf schema (``protocol.foxglove_schemas``), dtype and shape in
  the channel metadata;
- for viewing only: ``/<cam>/calibration`` foxglove.CameraCalibration, ``/<cam>/points``
  foxglove.PointCloud (every 5th frame), ``/tf`` foxglove.FrameTransforms (world to ``grasp`` and
  to each camera), ``/joint_states`` foxglove.JointStates.

Episode facts are in the ``episode`` metadata; policy episodes say why they ended (``end``:
success / timeout / unreachable / failed, plus ``unreachable_reason``); robot demos carry the
operator's ``keyframes`` and their ``scene_bounds``. Points are re-derived from depth with the
stored matrices, as the environment derived them.

Why this form for the exact arrays (measured in bench/bench_mcap_writer.py, BENCHMARKS.md): images
and depth travel once, inside Foxglove's own RawImage (its ``data`` is the array's bytes), where
the first layout stored each image twice (raw, and base64 in JSON): a 1-camera 128 px demo takes
0.37 MB instead of 1.01 (front + wrist: 1.93 instead of 3.58, float32 depth being most of it), and
writes in ~20 % less CPU; reading costs the same. The small arrays take a 25-float protobuf
message, so Foxglove decodes and plots them instead of flagging a schemaless channel; MCAP
attachments would also pass, but are stored uncompressed, one blob per array, with no per-frame
log time. Chunks are zstd (the SDK's default): LZ4 wrote 1.57x the bytes for 20 % less CPU.

Files of the first layout (``c2farm-demo/1``) still load (``protocol.episode_file_v1``): a demo
cache is keyed by task, cameras and size only, and robot demos cannot be re-recorded.

:func:`read_episode_view` reads only what a viewer needs (images, calibration, poses, actions),
without depth and points and without the simulator, so the dashboard can use it.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import foxglove
import numpy as np
from mcap.reader import make_reader

from protocol.episode_channels import ACTION_TOPIC, PROPRIO_SIZE, EpisodeChannels, depth_of, proprio_of
from protocol.mcap_protobuf import decode
from protocol.observation import ACTION_SIZE, Observation, camera_frame

__all__ = ["ACTION_SIZE", "ACTION_TOPIC", "PROPRIO_SIZE", "Demo", "DemoFileError", "EpisodeView", "depth_of",
           "load_demo", "proprio_of", "read_episode_view", "write_demo", "write_episode_mcap"]
FORMAT = "c2farm-demo/2"


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
    #: wall-clock ns of frame 0; None: the writer takes "now" for the last frame
    recorded_ns: int | None = None


def keyframes_problem(keyframes: object, frames: int) -> str:
    """Why ``keyframes`` are no demo's keyframes (increasing frame indices after frame 0), or ""."""
    if not isinstance(keyframes, list) or not all(type(k) is int for k in keyframes):
        return f"keyframes {keyframes!r} are not a list of frame indices"
    if any(not 0 < k < frames for k in keyframes) or keyframes != sorted(set(keyframes)):
        return f"keyframes {keyframes} are not increasing frames in 1..{frames - 1}"
    return ""


def episode_metadata(demo: Demo, cams: list[str], fmt: str = FORMAT) -> dict[str, str]:
    """The ``episode`` metadata record: the facts no channel carries."""
    return {
        "task": demo.task, "seed": str(demo.seed), "success": json.dumps(demo.success),
        "frames": str(len(demo.observations)), "cameras": json.dumps(cams),
        "waypoint_frames": json.dumps(demo.waypoint_frames), "control_hz": str(demo.control_hz),
        "attempts": str(demo.attempts), "format": fmt,
        **({"keyframes": json.dumps(demo.keyframes)} if demo.keyframes is not None else {}),
        **({"scene_bounds": json.dumps([float(b) for b in demo.scene_bounds])} if demo.scene_bounds else {}),
        **({"end": demo.end_reason, "unreachable_reason": demo.unreachable_reason} if demo.end_reason else {})}


def write_demo(path: str | Path, demo: Demo, points_every: int = 5) -> int:
    """Write ``demo``; returns the file size in bytes. Point-cloud previews every ``points_every`` frames."""
    path = Path(path)
    if demo.keyframes is not None and (problem := keyframes_problem(demo.keyframes, len(demo.observations))):
        raise ValueError(problem)
    obs = demo.observations
    cams = list(obs[0].cameras) if obs else []
    dt_ns = int(1e9 / demo.control_hz)
    start = demo.recorded_ns if demo.recorded_ns is not None else time.time_ns() - max(0, len(obs) - 1) * dt_ns
    ctx = foxglove.Context()  # this file's own: channels of concurrent writers never mix
    options = foxglove.mcap.MCAPWriteOptions(compression_threads=0)  # the actors' cores are busy
    with foxglove.open_mcap(path, allow_overwrite=True, context=ctx, writer_options=options) as w:
        channels = EpisodeChannels(ctx, with_actions=bool(demo.actions), points_every=points_every)
        for i, o in enumerate(obs):
            channels.log(o, start + i * dt_ns, demo.actions[i] if i < len(demo.actions) else None,
                         points=i % points_every == 0 or i == len(obs) - 1)
        w.write_metadata("episode", episode_metadata(demo, cams))
    return path.stat().st_size


@dataclass
class _RawEpisode:
    """The exact arrays of one file, by frame index, plus its ``episode`` metadata."""

    meta: dict[str, str]
    frames: int
    cameras: list[str]
    proprio: dict[int, np.ndarray]
    arrays: dict[tuple[str, str], dict[int, np.ndarray]]  #: by (camera, rgb / depth / calibration)
    actions: dict[int, np.ndarray]
    recorded_ns: int | None  #: log time of frame 0 (None: a first-layout file, whose times start at 0)


def _image(msg) -> np.ndarray:
    """The exact array in a RawImage (``rgb8`` or ``32FC1``), read-only and without a copy."""
    dtype, depth = {"rgb8": (np.uint8, 3), "32FC1": (np.dtype("<f4"), 1)}[msg.encoding]
    arr = np.frombuffer(msg.data, dtype=dtype)
    return arr.reshape(msg.height, msg.width, 3) if depth == 3 else arr.reshape(msg.height, msg.width)


def _read_arrays(reader, cams: list[str], kinds: tuple[str, ...]):
    """(proprio, arrays by (camera, kind), actions, first log time), each by frame index, of a current file."""
    topics = {"/raw/proprio": ("proprio", ""), ACTION_TOPIC: ("action", "")}
    for c in cams:
        topics.update({f"/{c}/image": (c, "rgb"), f"/{c}/depth": (c, "depth"),
                       f"/raw/{c}/calibration": (c, "calibration")})
    topics = {t: k for t, k in topics.items() if k[1] in ("", *kinds)}
    seen: dict[str, list] = {t: [] for t in topics}
    first = None
    for schema, channel, msg in reader.iter_messages(topics=list(topics)):
        m = decode(schema, msg.data)
        first = msg.log_time if first is None else min(first, msg.log_time)
        seen[channel.topic].append(_image(m) if schema.name == "foxglove.RawImage" else np.array(m.values, np.float32))
    proprio = dict(enumerate(seen.pop("/raw/proprio")))
    actions = dict(enumerate(seen.pop(ACTION_TOPIC)))
    return proprio, {topics[t]: dict(enumerate(v)) for t, v in seen.items()}, actions, first


def _read_raw(path: Path, kinds: tuple[str, ...]) -> _RawEpisode:
    """Read the file's exact arrays of ``kinds`` (rgb, depth, calibration); DemoFileError on any problem."""
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
            if ep.get("format") == FORMAT:
                proprio, arrays, actions, start = _read_arrays(reader, cams, kinds)
            elif ep.get("format") != "c2farm-demo/1":
                raise DemoFileError(path, f"format {ep.get('format')!r}: this reader knows {FORMAT} and c2farm-demo/1")
            else:
                from protocol.episode_file_v1 import read_arrays_v1

                (proprio, arrays, actions), start = read_arrays_v1(reader, kinds), None
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
    return _RawEpisode(ep, n, cams, proprio, arrays, actions, start)


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
                end_reason=ep.get("end", ""), unreachable_reason=ep.get("unreachable_reason", ""),
                recorded_ns=raw.recorded_ns)


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
