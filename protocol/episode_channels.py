"""An episode's channels on a foxglove-sdk context, frame by frame: the episode files
(``protocol.episode_file``) and the live view (``actors.live_view``) log the same messages, so what
Foxglove shows live is what the file shows later."""

from __future__ import annotations

import foxglove
import numpy as np
from foxglove import channels as fc
from foxglove.messages import FrameTransforms

from protocol import foxglove_schemas as fx
from protocol.observation import ACTION_SIZE, Observation

PROPRIO_SIZE = 25
ACTION_TOPIC = "/policy/next_best_pose"


def proprio_of(o: Observation) -> np.ndarray:
    """gripper_pose 7, gripper_open, fingers 2, joints 7, velocities 7, step: float32[25]."""
    return np.concatenate([o.gripper_pose, [o.gripper_open], o.finger_positions, o.joint_positions,
                           o.joint_velocities, [o.step]]).astype(np.float32)


def depth_of(points: np.ndarray, extrinsics: np.ndarray) -> np.ndarray:
    """Optical-axis depth of a world-frame organised cloud."""
    e = extrinsics.astype(np.float64)
    return ((points.astype(np.float64) - e[:3, 3]) @ e[:3, 2]).astype(np.float32)


class EpisodeChannels:
    """The channels of one episode on ``ctx``; a camera's channels open with its first frame."""

    def __init__(self, ctx: foxglove.Context, with_actions: bool = True, points_every: int = 5) -> None:
        self.ctx, self.points_every, self.frames = ctx, points_every, 0
        self.array_schema = foxglove.Schema(name=fx.ARRAY_SCHEMA, encoding="protobuf", data=fx.ARRAY_DESCRIPTOR)
        self.proprio = self._array("/raw/proprio", PROPRIO_SIZE)
        self.action = self._array(ACTION_TOPIC, ACTION_SIZE) if with_actions else None
        self.tf = fc.FrameTransformsChannel("/tf", context=ctx)
        self.joints = fc.JointStatesChannel("/joint_states", context=ctx)
        self.cameras: dict[str, tuple] = {}

    def _array(self, topic: str, shape: int | str) -> foxglove.Channel:
        return foxglove.Channel(topic, schema=self.array_schema, message_encoding="protobuf", context=self.ctx,
                                metadata={"dtype": "float32", "shape": str(shape)})

    def _camera(self, c: str) -> tuple:
        if c not in self.cameras:
            ctx = self.ctx
            self.cameras[c] = (fc.RawImageChannel(f"/{c}/image", context=ctx),
                               fc.RawImageChannel(f"/{c}/depth", context=ctx), self._array(f"/raw/{c}/calibration", 25),
                               fc.CameraCalibrationChannel(f"/{c}/calibration", context=ctx),
                               fc.PointCloudChannel(f"/{c}/points", context=ctx))
        return self.cameras[c]

    def log_action(self, action: np.ndarray, t: int) -> None:
        """A next-best pose (xyz, quat xyzw, gripper open) at ``t``."""
        if self.action is not None:
            self.action.log(fx.float32_array(np.asarray(action, np.float32).reshape(ACTION_SIZE)), log_time=t)

    def log(self, o: Observation, t: int, action: np.ndarray | None = None, points: bool | None = None) -> None:
        """Frame ``o`` at ``t`` (ns since the epoch); ``action``: the next-best pose chosen from it.
        Point clouds every ``points_every`` frames unless ``points`` says."""
        i, self.frames = self.frames, self.frames + 1
        points = i % self.points_every == 0 if points is None else points
        self.proprio.log(fx.float32_array(proprio_of(o)), log_time=t)
        if action is not None:
            self.log_action(action, t)
        self.joints.log(fx.joint_states(t, o.joint_positions, o.joint_velocities, o.finger_positions), log_time=t)
        tfs = [fx.transform(t, "grasp", o.gripper_pose)]
        for c, fr in o.cameras.items():
            image, depth, cal, info, cloud = self._camera(c)
            image.log(fx.raw_image(t, c, fr.rgb), log_time=t)
            depth.log(fx.raw_image(t, c, depth_of(fr.points, fr.extrinsics)), log_time=t)
            cal.log(fx.float32_array(np.concatenate([fr.intrinsics.flatten(), fr.extrinsics.flatten()])), log_time=t)
            info.log(fx.camera_calibration(t, c, fr.intrinsics, fr.rgb.shape[0]), log_time=t)
            if points:
                cloud.log(fx.point_cloud(t, fr.points, fr.rgb), log_time=t)
            tfs.append(fx.transform(t, c, fr.extrinsics))
        self.tf.log(FrameTransforms(transforms=tfs), log_time=t)
