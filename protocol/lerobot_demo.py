"""c2farm episodes (demo files) as LeRobot features, and back.

Per frame: ``observation.images.<cam>`` (RGB), ``observation.depth.<cam>`` (z-depth, metres,
H*W row-major), ``observation.intrinsics.<cam>`` (K, 9 row-major) and ``observation.extrinsics.<cam>``
(camera-to-world, OpenCV axes, 16 row-major), so world points re-derive as the demo file does
(``observation.points.<cam>``, H*W*3 world points, is read instead of depth when a dataset has it);
``observation.state`` (the proprioception, axes named below), ``observation.step`` (decisions
taken before the frame), ``action`` (the next-best pose: xyz, quaternion xyzw, gripper open),
``next.reward``, ``next.done`` and ``is_keyframe``. A demo's action at frame i is the next
keyframe's gripper pose and state (what the demo source trains on); a policy episode's is the
pose the policy chose there. The last frame holds its own pose. The reward is the task's success
reward on the last frame of a successful episode, else 0.

The episode's facts (seed, success, waypoints, where the keyframes came from, why a policy
episode ended) go in ``c2farm/...`` columns of the episodes table, so import rebuilds the file.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from protocol.episode_file import Demo
from protocol.lerobot_v3 import Episode
from protocol.observation import Observation, camera_frame

ROBOT_TYPE = "franka_panda"
POSE = ["x", "y", "z", "qx", "qy", "qz", "qw"]
STATE_NAMES = ([f"gripper_{a}" for a in POSE] + ["gripper_open", "finger_left", "finger_right"]
               + [f"joint{j}_position" for j in range(1, 8)] + [f"joint{j}_velocity" for j in range(1, 8)])
ACTION_NAMES = [*POSE, "gripper_open"]
IMAGE_NAMES = ["height", "width", "channels"]
K_NAMES = [f"k{r}{c}" for r in range(3) for c in range(3)]  #: the pinhole matrix, row-major
E_NAMES = [f"t{r}{c}" for r in range(4) for c in range(4)]  #: camera-to-world, row-major
#: depth is a flat row-major vector: lerobot-doctor 0.2 fails on constant rows of a 2-D array per frame
DEPTH_INFO = {"layout": "row-major z-depth along the optical axis", "unit": "m", "stats": "pooled"}
META_TYPES = {"c2farm/seed": pa.int64(), "c2farm/success": pa.bool_(), "c2farm/attempts": pa.int64(),
              "c2farm/waypoint_frames": pa.list_(pa.int64()), "c2farm/operator_keyframes": pa.bool_(),
              "c2farm/scene_bounds": pa.list_(pa.float64()), "c2farm/policy": pa.bool_(),
              "c2farm/end": pa.string(), "c2farm/unreachable_reason": pa.string()}


def features(cameras: list[str], size: int) -> dict[str, dict]:
    """The features of episodes from ``cameras`` at ``size`` pixels."""
    out: dict[str, dict] = {}
    for c in cameras:
        out[f"observation.images.{c}"] = {"dtype": "image", "shape": [size, size, 3], "names": IMAGE_NAMES}
        out[f"observation.depth.{c}"] = {"dtype": "float32", "shape": [size * size], "names": None,
                                         "info": {**DEPTH_INFO, "height": size, "width": size}}
        out[f"observation.intrinsics.{c}"] = {"dtype": "float32", "shape": [9], "names": K_NAMES}
        out[f"observation.extrinsics.{c}"] = {"dtype": "float32", "shape": [16], "names": E_NAMES}
    return {**out,
            "observation.state": {"dtype": "float32", "shape": [len(STATE_NAMES)], "names": STATE_NAMES},
            "observation.step": {"dtype": "int64", "shape": [1], "names": None},
            "action": {"dtype": "float32", "shape": [len(ACTION_NAMES)], "names": ACTION_NAMES},
            "next.reward": {"dtype": "float32", "shape": [1], "names": None},
            "next.done": {"dtype": "bool", "shape": [1], "names": None},
            "is_keyframe": {"dtype": "bool", "shape": [1], "names": None}}


def _depth(points: np.ndarray, extrinsics: np.ndarray) -> np.ndarray:
    """Optical-axis depth of a world-frame organised cloud (as the demo file stores it)."""
    e = extrinsics.astype(np.float64)
    return ((points.astype(np.float64) - e[:3, 3]) @ e[:3, 2]).astype(np.float32)


def _pose(o: Observation) -> np.ndarray:
    return np.concatenate([o.gripper_pose, [o.gripper_open]]).astype(np.float32)


def demo_episode(demo: Demo, keyframes: list[int], success_reward: float) -> Episode:
    """``demo`` as one LeRobot episode; ``keyframes`` are those it is learnt from."""
    obs, n = demo.observations, len(demo.observations)
    cams = list(obs[0].cameras)
    cols: dict[str, np.ndarray] = {}
    for c in cams:
        frames = [o.cameras[c] for o in obs]
        cols[f"observation.images.{c}"] = np.stack([f.rgb for f in frames])
        cols[f"observation.depth.{c}"] = np.stack([_depth(f.points, f.extrinsics).reshape(-1) for f in frames])
        cols[f"observation.intrinsics.{c}"] = np.stack([f.intrinsics.reshape(9) for f in frames]).astype(np.float32)
        cols[f"observation.extrinsics.{c}"] = np.stack([f.extrinsics.reshape(16) for f in frames]).astype(np.float32)
    cols["observation.state"] = np.stack([np.concatenate([
        o.gripper_pose, [o.gripper_open], o.finger_positions, o.joint_positions, o.joint_velocities]) for o in obs
    ]).astype(np.float32)
    cols["observation.step"] = np.array([o.step for o in obs], np.int64)
    if demo.actions:
        actions = [np.asarray(a, np.float32).reshape(-1) for a in demo.actions] + [_pose(obs[-1])]
    else:
        actions = [_pose(obs[next((k for k in keyframes if k > i), i)]) for i in range(n)]
    cols["action"] = np.stack(actions[:n])
    cols["next.reward"] = np.zeros(n, np.float32)
    cols["next.reward"][-1] = success_reward if demo.success else 0.0
    cols["next.done"] = np.arange(n) == n - 1
    cols["is_keyframe"] = np.isin(np.arange(n), keyframes)
    meta = {"c2farm/seed": demo.seed, "c2farm/success": demo.success, "c2farm/attempts": demo.attempts,
            "c2farm/waypoint_frames": list(demo.waypoint_frames),
            "c2farm/operator_keyframes": demo.keyframes is not None,
            "c2farm/scene_bounds": list(demo.scene_bounds or []), "c2farm/policy": bool(demo.actions),
            "c2farm/end": demo.end_reason, "c2farm/unreachable_reason": demo.unreachable_reason}
    return Episode(task=demo.task, columns=cols, meta=meta)


def cameras_of(features_: dict[str, dict]) -> list[str]:
    return [k.removeprefix("observation.images.") for k in features_ if k.startswith("observation.images.")]


def import_problem(features_: dict[str, dict]) -> str:
    """What a dataset lacks to become demo files (one line), or ""."""
    cams = cameras_of(features_)
    if not cams:
        return "no camera images (observation.images.<camera>)"
    lacks = []
    for c in cams:
        if f"observation.depth.{c}" not in features_ and f"observation.points.{c}" not in features_:
            lacks.append(f"depth or a point cloud for camera {c!r} (observation.depth.{c} or observation.points.{c})")
        for m in ("intrinsics", "extrinsics"):
            if f"observation.{m}.{c}" not in features_:
                lacks.append(f"the {m} of camera {c!r} (observation.{m}.{c})")
    state = features_.get("observation.state", {})
    if list(state.get("names") or []) != STATE_NAMES:
        lacks.append(f"c2farm's observation.state ({len(STATE_NAMES)} values: gripper pose, gripper open, fingers, "
                     "joint positions and velocities)")
    return "; ".join(lacks)


def episode_demo(ep: Episode, fps: int, task: str | None = None) -> Demo:
    """A demo file's Demo from one LeRobot episode with c2farm's features (see :func:`import_problem`)."""
    cols, meta, n = ep.columns, ep.meta, len(ep.columns["observation.state"])
    cams = cameras_of({k: {} for k in cols})
    state = cols["observation.state"].astype(np.float32)
    steps = cols["observation.step"].reshape(n) if "observation.step" in cols else np.zeros(n, np.int64)
    observations = []
    for i in range(n):
        frames = {}
        for c in cams:
            rgb = cols[f"observation.images.{c}"][i]
            k = cols[f"observation.intrinsics.{c}"][i].reshape(3, 3)
            e = cols[f"observation.extrinsics.{c}"][i].reshape(4, 4)
            if f"observation.depth.{c}" in cols:
                depth = cols[f"observation.depth.{c}"][i].reshape(rgb.shape[:2])
            else:
                depth = _depth(cols[f"observation.points.{c}"][i].reshape(*rgb.shape[:2], 3), e)
            frames[c] = camera_frame(rgb, depth, k, e)
        s = state[i]
        observations.append(Observation(cameras=frames, gripper_pose=s[0:7].copy(), gripper_open=float(s[7]),
                                        finger_positions=s[8:10].copy(), joint_positions=s[10:17].copy(),
                                        joint_velocities=s[17:24].copy(), step=int(steps[i])))
    marked = [int(i) for i in np.nonzero(cols["is_keyframe"].reshape(n))[0] if 0 < i < n] \
        if "is_keyframe" in cols else []
    given = meta.get("c2farm/operator_keyframes")
    keyframes = (marked if given else None) if given is not None else (marked or None)
    policy = bool(meta.get("c2farm/policy"))
    return Demo(task=task or ep.task, seed=int(meta.get("c2farm/seed", meta.get("episode_index", 0))),
                success=bool(meta.get("c2farm/success", True)), observations=observations,
                waypoint_frames=list(meta.get("c2farm/waypoint_frames") or []), keyframes=keyframes,
                scene_bounds=tuple(meta["c2farm/scene_bounds"]) if meta.get("c2farm/scene_bounds") else None,
                control_hz=int(fps), attempts=int(meta.get("c2farm/attempts", 1)),
                actions=[a.copy() for a in cols["action"][:-1]] if policy else [],
                end_reason=meta.get("c2farm/end") or "", unreachable_reason=meta.get("c2farm/unreachable_reason") or "")
