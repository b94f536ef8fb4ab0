"""An episode as it travels from an actor (or a demo source, or a real robot) to the replay.

Observations are stacked over time into named arrays, so an episode of T decisions holds
T + 1 observations (the last one is the state after the last action) and T steps. Names
follow one flat scheme that the replay server, the learner and the demo files share:

- per camera ``c``: ``{c}_rgb`` uint8 [H, W, 3], ``{c}_points`` float16/32 [H, W, 3],
  ``{c}_intrinsics`` float32 [3, 3], ``{c}_extrinsics`` float32 [4, 4];
- proprioception: ``gripper_pose`` [7], ``gripper_open`` [], ``finger_positions`` [2],
  ``joint_positions`` [7], ``joint_velocities`` [7], ``step`` int32 [];
- anything else an environment wants to keep, prefixed ``extra_`` (the act-time labels
  ``extra_voxel_indices`` [D, 3], ``extra_attention_coordinates`` [D, 3] and
  ``extra_rot_grip_indices`` [4] among them).

Only point clouds (``*_points``) may hold NaN or infinities; every other float is finite.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from protocol.codec import WIRE_DTYPES, ProtocolError, check_array_values, check_int, check_map, check_name
from protocol.keys import MAX_ID_LENGTH, is_valid_id
from protocol.limits import DEFAULT_LIMITS, MAX_INT, Limits
from protocol.observation import ACTION_SIZE, CameraFrame, Observation
from protocol.transition import ACT_LABELS, EXTRA_PREFIX, NEXT, extra_name

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
#: Default limits that keep one episode from exhausting a receiver (see ``protocol.limits``).
MAX_STEPS = DEFAULT_LIMITS.max_steps
MAX_CAMERAS = DEFAULT_LIMITS.max_cameras
MAX_IMAGE_SIDE = DEFAULT_LIMITS.max_image_side


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

    def validate(self, limits: Limits = DEFAULT_LIMITS) -> None:
        """Raise :class:`ProtocolError` naming the first field that breaks the schema."""
        validate_episode(self, limits)


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


def is_point_cloud(name: str) -> bool:
    """Arrays that may hold NaN: ``*_points`` (and a batch's ``*_points_tp1``)."""
    return name.removesuffix(NEXT).endswith("_points")


def validate_episode(ep: Episode, limits: Limits = DEFAULT_LIMITS) -> None:
    """Check every field and array: presence, type, dtype, shape, bounds and values.

    Cheap enough to run on every receipt (the large point clouds and images are not
    scanned). Non-finite numbers are refused everywhere except point clouds (any array
    named ``*_points``): real depth cameras report invalid depth as NaN and the voxeliser
    drops non-finite points, while a NaN in an action, reward, pose, camera matrix or
    act-time label would reach a loss.
    """
    _check_id("actor_id", ep.actor_id)
    check_int("episode_id", ep.episode_id)
    _check_id("task", ep.task)
    check_int("seed", ep.seed)
    for name in ("is_demo", "success", "timeout"):
        if not isinstance(getattr(ep, name), bool):
            raise ProtocolError(name, f"expected bool, got {type(getattr(ep, name)).__name__}")
    check_map("info", ep.info, limits, "text")

    _check_array("actions", ep.actions, ("float32",), ndim=2)
    steps = ep.actions.shape[0]
    if not 1 <= steps <= limits.max_steps:
        raise ProtocolError("actions", f"{steps} steps; an episode has 1..{limits.max_steps}")
    if ep.actions.shape[1] != ACTION_SIZE:
        raise ProtocolError("actions", f"shape {ep.actions.shape}, expected [T, {ACTION_SIZE}]")
    check_array_values("actions", ep.actions)
    for name, array, dtypes in (
        ("rewards", ep.rewards, ("float32",)),
        ("terminals", ep.terminals, ("bool",)),
        ("policy_versions", ep.policy_versions, ("int64",)),
    ):
        _check_array(name, array, dtypes, ndim=1)
        if array.shape[0] != steps:
            raise ProtocolError(name, f"length {array.shape[0]}, expected {steps} (one per step)")
        check_array_values(name, array)
    if steps and not (-1 <= ep.policy_versions.min() and ep.policy_versions.max() <= MAX_INT):
        raise ProtocolError("policy_versions", f"outside -1..{MAX_INT} (-1 marks a demo step)")

    obs = ep.observations
    if not isinstance(obs, dict):
        raise ProtocolError("observations", f"expected a dict of arrays, got {type(obs).__name__}")
    for name, array in obs.items():
        where = f"observations.{check_name(name, 'observations', limits)}"
        if not isinstance(array, np.ndarray) or array.dtype not in WIRE_DTYPES:
            raise ProtocolError(where, f"dtype {getattr(array, 'dtype', type(array).__name__)} cannot go on the wire")
        if array.ndim == 0 or array.shape[0] != steps + 1:
            raise ProtocolError(where, f"leading length {array.shape[:1]}, expected {steps + 1} (T + 1)")
        if array.ndim > limits.max_ndim:
            raise ProtocolError(where, f"{array.ndim} dimensions exceeds the limit of {limits.max_ndim}")
    for name, (shape, dtypes) in PROPRIO_ARRAYS.items():
        if name not in obs:
            raise ProtocolError(f"observations.{name}", "missing")
        _check_array(f"observations.{name}", obs[name], dtypes, ndim=1 + len(shape))
        if obs[name].shape[1:] != shape:
            raise ProtocolError(f"observations.{name}", f"shape {obs[name].shape[1:]}, expected {shape}")
        check_array_values(f"observations.{name}", obs[name])
    if obs["step"].min() < 0:
        raise ProtocolError("observations.step", "must be >= 0")

    cameras = ep.cameras
    if not 1 <= len(cameras) <= limits.max_cameras:
        raise ProtocolError("observations", f"{len(cameras)} cameras; an episode has 1..{limits.max_cameras}")
    for cam in cameras:
        _validate_camera(obs, cam, limits)
    known = set(PROPRIO_ARRAYS) | {c + s for c in cameras for s in CAMERA_SUFFIXES}
    extras = [name for name in obs if name not in known]
    for name in extras:
        if not name.startswith(EXTRA_PREFIX):
            raise ProtocolError(f"observations.{name}", "unknown array (extras need the 'extra_' prefix)")
    if len(extras) > limits.max_extras:
        raise ProtocolError("observations", f"{len(extras)} extras exceeds the limit of {limits.max_extras}")
    for name in extras:
        check_array_values(f"observations.{name}", obs[name], finite=not is_point_cloud(name))
    _validate_act_labels(obs, limits)


def _validate_camera(obs: dict[str, np.ndarray], cam: str, limits: Limits) -> None:
    if cam.startswith(EXTRA_PREFIX) or not is_valid_id(cam):
        raise ProtocolError(f"observations.{cam}_rgb", "not a camera name (and an extra cannot end in '_rgb')")
    for suffix in CAMERA_SUFFIXES:
        if cam + suffix not in obs:
            raise ProtocolError(f"observations.{cam}{suffix}", "missing")
    rgb, points = obs[f"{cam}_rgb"], obs[f"{cam}_points"]
    _check_array(f"observations.{cam}_rgb", rgb, ("uint8",), ndim=4)
    _check_array(f"observations.{cam}_points", points, ("float16", "float32"), ndim=4)
    height, width, channels = rgb.shape[1:]
    side = limits.max_image_side
    if channels != 3 or not (1 <= height <= side and 1 <= width <= side):
        raise ProtocolError(
            f"observations.{cam}_rgb", f"shape {rgb.shape[1:]}, expected [H, W, 3] with H, W in 1..{side}"
        )
    if points.shape != rgb.shape:
        raise ProtocolError(
            f"observations.{cam}_points", f"shape {points.shape} does not match rgb {rgb.shape}"
        )
    for suffix, shape in (("_intrinsics", (3, 3)), ("_extrinsics", (4, 4))):
        array = obs[cam + suffix]
        _check_array(f"observations.{cam}{suffix}", array, ("float32",), ndim=3)
        if array.shape[1:] != shape:
            raise ProtocolError(f"observations.{cam}{suffix}", f"shape {array.shape[1:]}, expected {shape}")
        check_array_values(f"observations.{cam}{suffix}", array)


def _validate_act_labels(obs: dict[str, np.ndarray], limits: Limits) -> None:
    """The cascade's act-time choices: shapes agree on one depth count D, indices are >= 0.

    Whether an index fits the learner's voxel grid or rotation bins is the learner's check:
    the wire does not know the network config.
    """
    depths = None
    for label, (shape, dtypes) in ACT_LABELS.items():
        name = extra_name(label)
        if name not in obs:
            continue
        array = obs[name]
        _check_array(f"observations.{name}", array, dtypes, ndim=1 + len(shape))
        want = tuple(array.shape[1] if d == "D" else d for d in shape)
        if array.shape[1:] != want:
            raise ProtocolError(f"observations.{name}", f"shape {array.shape[1:]}, expected {shape}")
        if "D" in shape:
            if depths is None:
                depths = array.shape[1]
            if array.shape[1] != depths or not 1 <= depths <= limits.max_depths:
                raise ProtocolError(
                    f"observations.{name}", f"{array.shape[1]} depths; labels need one D in 1..{limits.max_depths}"
                )
        if array.dtype.kind == "i" and array.size and array.min() < 0:
            raise ProtocolError(f"observations.{name}", "indices must be >= 0")


def _check_id(name: str, value) -> None:
    if not is_valid_id(value):
        shown = repr(value[:80]) if isinstance(value, str) else type(value).__name__
        raise ProtocolError(name, f"invalid id {shown}: use 1-{MAX_ID_LENGTH} letters, digits, '_', '.', '-'")


def _check_array(name: str, array, dtypes: tuple[str, ...], ndim: int) -> None:
    if not isinstance(array, np.ndarray):
        raise ProtocolError(name, f"expected an array, got {type(array).__name__}")
    if array.dtype.name not in dtypes:
        raise ProtocolError(name, f"dtype {array.dtype}, expected one of {dtypes}")
    if array.ndim != ndim:
        raise ProtocolError(name, f"{array.ndim} dimensions, expected {ndim}")
