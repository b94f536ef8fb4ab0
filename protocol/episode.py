"""An episode as it travels from an actor (or a demo source, or a real robot) to the replay.

Observations are stacked over time into named arrays, so an episode of T decisions holds
T + 1 observations (the last one is the state after the last action) and T steps. Names
follow one flat scheme that the replay server, the learner and the demo files share:

- per camera ``c``: ``{c}_rgb`` uint8 [H, W, 3], ``{c}_points`` float16/32 [H, W, 3],
  ``{c}_intrinsics`` float32 [3, 3], ``{c}_extrinsics`` float32 [4, 4];
- proprioception: ``gripper_pose`` [7], ``gripper_open`` [], ``finger_positions`` [2],
  ``joint_positions`` [7], ``joint_velocities`` [7], ``step`` int32 [];
- anything else an environment wants to keep, prefixed ``extra_``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from protocol.codec import ProtocolError
from protocol.observation import ACTION_SIZE, CameraFrame, Observation

#: Per-observation proprioceptive arrays: name -> (trailing shape, allowed dtypes).
PROPRIO_ARRAYS: dict[str, tuple[tuple[int, ...], tuple[str, ...]]] = {
    "gripper_pose": ((7,), ("float32", "float64")),
    "gripper_open": ((), ("float32", "float64")),
    "finger_positions": ((2,), ("float32", "float64")),
    "joint_positions": ((7,), ("float32", "float64")),
    "joint_velocities": ((7,), ("float32", "float64")),
    "step": ((), ("int32", "int64")),
}
CAMERA_SUFFIXES = ("_rgb", "_points", "_intrinsics", "_extrinsics")
EXTRA_PREFIX = "extra_"

#: Hard limits that keep one message from exhausting a receiver.
MAX_STEPS = 1000
MAX_CAMERAS = 8
MAX_IMAGE_SIDE = 1024


@dataclass
class Episode:
    """One finished episode, or one demo-augmented keyframe episode (``is_demo``)."""

    actor_id: str  #: who produced it; (actor_id, episode_id) identifies it for dedup and acks
    episode_id: int  #: increasing per actor
    task: str  #: task name, e.g. "reach_target"
    seed: int  #: environment seed of this episode
    is_demo: bool  #: demonstration (or demo-augmented) data rather than policy data
    success: bool  #: the task was solved
    timeout: bool  #: ended by the episode-length limit rather than by success or failure
    observations: dict[str, np.ndarray]  #: named arrays, each [T + 1, ...]
    actions: np.ndarray  #: float32 [T, 8] next-best poses: xyz, quaternion xyzw, gripper open
    rewards: np.ndarray  #: float32 [T]
    terminals: np.ndarray  #: bool [T]: the episode ended after this step
    policy_versions: np.ndarray  #: int64 [T]: weights version that chose each action (-1: demo)
    info: dict[str, str] = field(default_factory=dict)  #: free-form, e.g. why it ended

    @property
    def num_steps(self) -> int:
        return int(self.actions.shape[0])

    @property
    def cameras(self) -> list[str]:
        return sorted(k[: -len("_rgb")] for k in self.observations if k.endswith("_rgb"))

    @property
    def key(self) -> tuple[str, int]:
        return (self.actor_id, self.episode_id)

    def observation(self, t: int) -> Observation:
        """Observation ``t`` (0..T) as the structured type the environment produced."""
        obs = self.observations
        return Observation(
            cameras={
                c: CameraFrame(
                    rgb=obs[f"{c}_rgb"][t],
                    points=obs[f"{c}_points"][t],
                    intrinsics=obs[f"{c}_intrinsics"][t],
                    extrinsics=obs[f"{c}_extrinsics"][t],
                )
                for c in self.cameras
            },
            gripper_pose=obs["gripper_pose"][t],
            gripper_open=float(obs["gripper_open"][t]),
            finger_positions=obs["finger_positions"][t],
            joint_positions=obs["joint_positions"][t],
            joint_velocities=obs["joint_velocities"][t],
            step=int(obs["step"][t]),
            extras={k[len(EXTRA_PREFIX) :]: v[t] for k, v in obs.items() if k.startswith(EXTRA_PREFIX)},
        )

    def validate(self) -> None:
        """Raise :class:`ProtocolError` naming the first field that breaks the schema."""
        validate_episode(self)


def stack_observations(observations: list[Observation], points_dtype=np.float16) -> dict[str, np.ndarray]:
    """Flatten and stack structured observations into the wire's named arrays."""
    if not observations:
        raise ProtocolError("observations", "an episode needs at least one observation")
    columns: dict[str, list[np.ndarray]] = {}

    def put(name: str, value) -> None:
        columns.setdefault(name, []).append(np.asarray(value))

    for obs in observations:
        for cam, frame in obs.cameras.items():
            put(f"{cam}_rgb", frame.rgb)
            put(f"{cam}_points", np.asarray(frame.points, dtype=points_dtype))
            put(f"{cam}_intrinsics", np.asarray(frame.intrinsics, dtype=np.float32))
            put(f"{cam}_extrinsics", np.asarray(frame.extrinsics, dtype=np.float32))
        put("gripper_pose", np.asarray(obs.gripper_pose, dtype=np.float32))
        put("gripper_open", np.float32(obs.gripper_open))
        put("finger_positions", np.asarray(obs.finger_positions, dtype=np.float32))
        put("joint_positions", np.asarray(obs.joint_positions, dtype=np.float32))
        put("joint_velocities", np.asarray(obs.joint_velocities, dtype=np.float32))
        put("step", np.int32(obs.step))
        for name, value in obs.extras.items():
            put(EXTRA_PREFIX + name, value)
    lengths = {name: len(values) for name, values in columns.items()}
    if len(set(lengths.values())) != 1:
        raise ProtocolError("observations", f"not every observation has the same arrays: {lengths}")
    return {name: np.stack(values) for name, values in columns.items()}


def validate_episode(ep: Episode) -> None:
    """Check every array's presence, dtype and shape; cheap enough to run on every receipt."""
    if not ep.actor_id or len(ep.actor_id) > 128:
        raise ProtocolError("actor_id", "must be a non-empty string of at most 128 characters")
    if ep.episode_id < 0:
        raise ProtocolError("episode_id", "must be >= 0")
    _check_array("actions", ep.actions, ("float32",), ndim=2)
    steps = ep.actions.shape[0]
    if not 1 <= steps <= MAX_STEPS:
        raise ProtocolError("actions", f"{steps} steps; an episode has 1..{MAX_STEPS}")
    if ep.actions.shape[1] != ACTION_SIZE:
        raise ProtocolError("actions", f"shape {ep.actions.shape}, expected [T, {ACTION_SIZE}]")
    for name, array, dtypes in (
        ("rewards", ep.rewards, ("float32",)),
        ("terminals", ep.terminals, ("bool",)),
        ("policy_versions", ep.policy_versions, ("int64",)),
    ):
        _check_array(name, array, dtypes, ndim=1)
        if array.shape[0] != steps:
            raise ProtocolError(name, f"length {array.shape[0]}, expected {steps} (one per step)")
    if not np.isfinite(ep.actions).all() or not np.isfinite(ep.rewards).all():
        raise ProtocolError("actions", "actions and rewards must be finite")

    obs = ep.observations
    for name, (shape, dtypes) in PROPRIO_ARRAYS.items():
        if name not in obs:
            raise ProtocolError(f"observations.{name}", "missing")
        _check_array(f"observations.{name}", obs[name], dtypes, ndim=1 + len(shape))
        if obs[name].shape[1:] != shape:
            raise ProtocolError(f"observations.{name}", f"shape {obs[name].shape[1:]}, expected {shape}")
    cameras = ep.cameras
    if not 1 <= len(cameras) <= MAX_CAMERAS:
        raise ProtocolError("observations", f"{len(cameras)} cameras; an episode has 1..{MAX_CAMERAS}")
    for cam in cameras:
        _validate_camera(obs, cam)
    known = set(PROPRIO_ARRAYS) | {c + s for c in cameras for s in CAMERA_SUFFIXES}
    for name, array in obs.items():
        if name not in known and not name.startswith(EXTRA_PREFIX):
            raise ProtocolError(f"observations.{name}", "unknown array (extras need the 'extra_' prefix)")
        if array.ndim == 0 or array.shape[0] != steps + 1:
            raise ProtocolError(
                f"observations.{name}", f"leading length {array.shape[:1]}, expected {steps + 1} (T + 1)"
            )


def _validate_camera(obs: dict[str, np.ndarray], cam: str) -> None:
    for suffix in CAMERA_SUFFIXES:
        if cam + suffix not in obs:
            raise ProtocolError(f"observations.{cam}{suffix}", "missing")
    rgb, points = obs[f"{cam}_rgb"], obs[f"{cam}_points"]
    _check_array(f"observations.{cam}_rgb", rgb, ("uint8",), ndim=4)
    _check_array(f"observations.{cam}_points", points, ("float16", "float32"), ndim=4)
    height, width, channels = rgb.shape[1:]
    if channels != 3 or not (1 <= height <= MAX_IMAGE_SIDE and 1 <= width <= MAX_IMAGE_SIDE):
        raise ProtocolError(f"observations.{cam}_rgb", f"shape {rgb.shape[1:]}, expected [H, W, 3]")
    if points.shape != rgb.shape:
        raise ProtocolError(
            f"observations.{cam}_points", f"shape {points.shape} does not match rgb {rgb.shape}"
        )
    for suffix, shape in (("_intrinsics", (3, 3)), ("_extrinsics", (4, 4))):
        array = obs[cam + suffix]
        _check_array(f"observations.{cam}{suffix}", array, ("float32",), ndim=3)
        if array.shape[1:] != shape:
            raise ProtocolError(f"observations.{cam}{suffix}", f"shape {array.shape[1:]}, expected {shape}")


def _check_array(name: str, array, dtypes: tuple[str, ...], ndim: int) -> None:
    if not isinstance(array, np.ndarray):
        raise ProtocolError(name, f"expected an array, got {type(array).__name__}")
    if array.dtype.name not in dtypes:
        raise ProtocolError(name, f"dtype {array.dtype}, expected one of {dtypes}")
    if array.ndim != ndim:
        raise ProtocolError(name, f"{array.ndim} dimensions, expected {ndim}")
