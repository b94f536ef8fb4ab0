"""The evaluator's scene live in Foxglove, through foxglove-sdk's WebSocket server.

In Foxglove, "Open connection" to ``ws://127.0.0.1:PORT`` (subprotocol ``foxglove.sdk.v1``). The
channels and messages are those of the episode files (``protocol.episode_channels``), so a layout
made for a recorded evaluation episode fits the live one. The server has no authentication: it
binds loopback unless told otherwise (reach it from elsewhere through an SSH tunnel).

    with LiveView(port=8765) as live:
        env = live.wrap(env)  # every reset and step is shown as it happens
"""

from __future__ import annotations

import time

import foxglove
import numpy as np

from protocol.episode_channels import EpisodeChannels
from protocol.observation import Observation


class LiveView:
    """A WebSocket server showing frames and next-best poses on the episode files' channels."""

    def __init__(self, port: int = 8765, host: str = "127.0.0.1", points_every: int = 1) -> None:
        self.ctx = foxglove.Context()  # its own: nothing else logged in this process reaches the viewers
        self.server = foxglove.start_server(name="c2farm", host=host, port=port, context=self.ctx)
        self.channels = EpisodeChannels(self.ctx, with_actions=True, points_every=points_every)

    @property
    def port(self) -> int:
        """The port it listens on (the one picked when asked for 0)."""
        return self.server.port

    def show(self, observation: Observation) -> None:
        self.channels.log(observation, time.time_ns())

    def show_action(self, action: np.ndarray) -> None:
        self.channels.log_action(action, time.time_ns())

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
