"""Is this payload an episode this replay accepts? ``protocol`` decodes it under the replay's
own limits (bytes, steps, cameras), which also refuses non-finite numbers outside point clouds.

Everything raises :class:`protocol.codec.ProtocolError` only (its reason is named by
``rejections.protocol_reason``), so one ``except ProtocolError`` handles every refusal.
"""
from __future__ import annotations

import dataclasses

from protocol.episode import Episode
from protocol.limits import DEFAULT_LIMITS, Limits
from protocol.messages import decode
from replay_server.config import ReplayConfig


def decode_limits(config: ReplayConfig, **overrides) -> Limits:
    """The protocol limits for episodes sent to this replay (``overrides`` for other messages)."""
    values = {"max_bytes": config.max_episode_bytes, "max_steps": config.max_episode_steps,
              "max_cameras": config.max_episode_cameras} | overrides
    return dataclasses.replace(DEFAULT_LIMITS, **values)


def decode_episode(data, config: ReplayConfig, limits: Limits | None = None) -> Episode:
    """Decode and validate one episode under this replay's limits; raises ProtocolError only.

    This is the one check an episode gets on its way in: ``protocol`` validates every field while
    decoding, against ``limits`` (by default :func:`decode_limits` of ``config``).
    """
    return decode(data, expect=Episode, limits=limits or decode_limits(config))
