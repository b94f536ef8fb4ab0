"""The wire: typed, versioned messages, their codec, key expressions and the Zenoh session.

This is the only package every role imports; it needs numpy, safetensors and zenoh, not torch.
"""

from protocol.codec import PROTOCOL_VERSION, ProtocolError
from protocol.episode import Episode, stack_observations
from protocol.fabric import FabricConfig, open_session, zenoh_config
from protocol.limits import DEFAULT_LIMITS, MAX_INT, Limits
from protocol.messages import (
    AckStatus,
    EpisodeAck,
    PriorityUpdate,
    SampleBatch,
    SampleRequest,
    Status,
    WeightsUpdate,
    decode,
    encode,
    validate,
)
from protocol.observation import ACTION_SIZE, CAMERA_NAMES, CameraFrame, Observation

__all__ = [
    "ACTION_SIZE",
    "AckStatus",
    "CAMERA_NAMES",
    "CameraFrame",
    "DEFAULT_LIMITS",
    "Episode",
    "EpisodeAck",
    "FabricConfig",
    "Limits",
    "MAX_INT",
    "Observation",
    "PROTOCOL_VERSION",
    "PriorityUpdate",
    "ProtocolError",
    "SampleBatch",
    "SampleRequest",
    "Status",
    "WeightsUpdate",
    "decode",
    "encode",
    "open_session",
    "stack_observations",
    "validate",
    "zenoh_config",
]
