"""The evaluator's (or the robot's) scene live in Foxglove, through foxglove-sdk's WebSocket server.

In Foxglove, "Open connection" to ``ws://127.0.0.1:PORT`` (subprotocol ``foxglove.sdk.v1``). The
frames and next-best poses are on the episode files' channels (``protocol.episode_channels``:
``/<camera>/image``, ``/<camera>/depth``, ``/<camera>/points``, ``/<camera>/calibration``, ``/tf``,
``/joint_states``, ``/policy/next_best_pose``), so a layout made for a recorded evaluation episode
fits the live one.
Live only, each decision's attention (``show_decision``):

- ``/policy/attention`` (``foxglove.SceneUpdate``, frame ``world``): one entity per depth,
  ``depth0`` .. ``depth{D-1}``: a translucent cube for the box that depth voxelised, a solid one
  at the voxel it chose (a voxel's size), and its ``TOP_VOXELS`` best voxels as small cubes
  coloured by Q, blue (the lowest of the K) to red (the highest);
- ``/tf`` frame ``next_best_pose``: the pose the arm is about to be sent to (beside ``grasp``,
  where the gripper is).

The server has no authentication: it binds loopback unless told otherwise (reach it from
elsewhere through an SSH tunnel).

    with LiveView(port=8765) as live:
        env = live.wrap(env)  # every reset and step is shown as it happens
        rollout(env, agent, cameras, seed, explore=False, on_decision=live.show_decision)
"""

from __future__ import annotations

import time

import foxglove
import numpy as np
from foxglove import channels as fc
from foxglove import messages as m

from protocol import foxglove_schemas as fx
from protocol.episode_channels import EpisodeChannels
from protocol.observation import Observation
from qattention.cascade import ActResult

ATTENTION_TOPIC = "/policy/attention"
NEXT_BEST_POSE_FRAME = "next_best_pose"
CHOSEN = m.Color(r=1.0, g=0.85, b=0.0, a=1.0)  #: the voxel a depth chose
BOX_ALPHA = 0.08  #: a depth's box: see-through, the scene stays visible inside it
TOP_SCALE = 0.5  #: a best voxel's cube, as a share of a voxel's edge: the chosen one stays visible around it


class LiveView:
    """A WebSocket server showing frames and next-best poses on the episode files' channels."""

    def __init__(self, port: int = 8765, host: str = "127.0.0.1", points_every: int = 1) -> None:
        self.ctx = foxglove.Context()  # its own: nothing else logged in this process reaches the viewers
        self.server = foxglove.start_server(name="c2farm", host=host, port=port, context=self.ctx)
        self.channels = EpisodeChannels(self.ctx, with_actions=True, points_every=points_every)
        self.attention = fc.SceneUpdateChannel(ATTENTION_TOPIC, context=self.ctx)

    @property
    def port(self) -> int:
        """The port it listens on (the one picked when asked for 0)."""
        return self.server.port

    def show(self, observation: Observation) -> None:
        self.channels.log(observation, time.time_ns())

    def show_action(self, action: np.ndarray) -> None:
        self.channels.log_action(action, time.time_ns())

    def show_decision(self, observation: Observation, act: ActResult) -> None:
        """The cascade's decision on ``observation`` (the batch's first): its attention and next-best pose."""
        t = time.time_ns()
        self.attention.log(attention_scene(t, act, step=observation.step), log_time=t)
        pose = fx.transform(t, NEXT_BEST_POSE_FRAME, act.action[0, :7])
        self.channels.tf.log(m.FrameTransforms(transforms=[pose]), log_time=t)

    def wrap(self, env) -> LiveEnv:
        """``env`` with every reset's and step's observation (and each step's pose) shown."""
        return LiveEnv(env, self)

    def close(self) -> None:
        self.server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class LiveEnv:
    """An environment that shows what it does: ``reset`` and ``step`` as the wrapped one, the rest passed through."""

    def __init__(self, env, view: LiveView) -> None:
        self._env, self._view = env, view

    def reset(self, *args, **kwargs):
        obs = self._env.reset(*args, **kwargs)
        self._view.show(obs)
        return obs

    def step(self, action, *args, **kwargs):
        self._view.show_action(action)
        result = self._env.step(action, *args, **kwargs)
        self._view.show(result.observation)
        return result

    def __getattr__(self, name: str):
        return getattr(self._env, name)


def attention_scene(t_ns: int, act: ActResult, step: int = 0, i: int = 0) -> m.SceneUpdate:
    """Sample ``i``'s decision as one entity per depth: its box, its chosen voxel, its best voxels by Q."""
    entities = []
    for d, bounds in enumerate(act.bounds[i]):
        lo, hi = bounds[:3].astype(np.float64), bounds[3:].astype(np.float64)
        voxel = (hi - lo) / act.voxel_size
        top = act.top_voxels[i, d]
        q = top[:, 3]
        share = (q - q.min()) / (q.max() - q.min()) if q.max() > q.min() else np.ones_like(q)
        cubes = [_cube((lo + hi) / 2, hi - lo, _depth_colour(d, BOX_ALPHA)),
                 _cube(act.attention_coordinates[i, d], voxel, CHOSEN)]
        cubes += [_cube(xyz, voxel * TOP_SCALE, m.Color(r=float(s), g=0.0, b=float(1 - s), a=0.8))
                  for xyz, s in zip(top[:, :3], share)]
        meta = [("step", str(step)), ("q_chosen", f"{act.q_values[i, d]:.4g}"), ("q_best", f"{q.max():.4g}"),
                ("q_kth", f"{q.min():.4g}")]
        entities.append(m.SceneEntity(timestamp=fx.stamp(t_ns), frame_id="world", id=f"depth{d}", cubes=cubes,
                                      metadata=[m.KeyValuePair(key=k, value=v) for k, v in meta]))
    return m.SceneUpdate(entities=entities)


def _cube(centre, size, colour: m.Color) -> m.CubePrimitive:
    return m.CubePrimitive(pose=m.Pose(position=m.Vector3(**dict(zip("xyz", map(float, centre)))),
                                       orientation=m.Quaternion(w=1.0)),
                           size=m.Vector3(**dict(zip("xyz", map(float, size)))), color=colour)


def _depth_colour(d: int, alpha: float) -> m.Color:
    """Depth 0 cyan, 1 magenta, 2 green, ...: boxes of different depths tell apart where they overlap."""
    r, g, b = ((0.0, 0.8, 1.0), (1.0, 0.0, 0.8), (0.2, 1.0, 0.2))[d % 3]
    return m.Color(r=r, g=g, b=b, a=alpha)
