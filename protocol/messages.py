"""Every message the roles exchange, and the one pair of functions that (de)serialise them.

``encode(message) -> bytes`` and ``decode(data, expect=...) -> message``. Decoding checks the
frame, the version, the kind and the schema, and raises :class:`ProtocolError` (naming the
field at fault) for anything else; receivers count those and keep serving.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Union

import numpy as np

from protocol.codec import DEFAULT_MAX_BYTES, ProtocolError, decode_frame, encode_frame, require
from protocol.episode import Episode, validate_episode


class Kind(enum.IntEnum):
    EPISODE = 1
    ACK = 2
    WEIGHTS = 3
    STATUS = 4
    SAMPLE_REQUEST = 5
    SAMPLE_BATCH = 6
    PRIORITY_UPDATE = 7


class AckStatus(str, enum.Enum):
    STORED = "stored"  #: newly stored
    DUPLICATE = "duplicate"  #: already stored earlier; not stored again
    REJECTED = "rejected"  #: will never be stored (the reason says why); do not resend


@dataclass
class EpisodeAck:
    """The replay server's answer to one episode, sent back to the actor that produced it."""

    actor_id: str
    episode_id: int
    status: AckStatus
    reason: str = ""


@dataclass
class WeightsUpdate:
    """A versioned snapshot of the online Q-attention networks, broadcast by the learner."""

    version: int  #: strictly increasing per run
    learner_step: int  #: update() calls done when the snapshot was taken
    tensors: dict[str, np.ndarray]  #: parameter name -> array (float32, or float16 to halve the size)
    config_digest: str = ""  #: hash of the network config, so an actor can refuse a mismatch
    published_at: float = 0.0  #: sender's wall clock (s since the epoch): receivers measure broadcast latency
    env_steps: int = 0  #: transitions the replay had received when published, demos included (learning curves)


@dataclass
class Status:
    """A role's heartbeat: who it is and its counters, published about once a second."""

    role: str  #: "replay", "learner", "actor", "dashboard", "router", ...
    instance: str  #: unique within the role, e.g. "actor-3"
    run_id: str
    pid: int
    host: str
    time: float  #: seconds since the epoch, sender's clock
    state: str = "running"  #: "starting", "running", "stopping", ...
    counters: dict[str, float] = field(default_factory=dict)  #: numbers for the dashboard
    info: dict[str, str] = field(default_factory=dict)  #: short strings (version, task, last error)


@dataclass
class SampleRequest:
    """The learner asks the replay server for one batch (several may be in flight)."""

    request_id: int  #: echoed in the answer, so pipelined answers can be matched
    batch_size: int
    timeout_ms: int = 10_000  #: the server answers with an error rather than wait longer


@dataclass
class SampleBatch:
    """B sampled transitions as named arrays (observation t, ``*_tp1`` for t + 1, step arrays,
    ``indices``/``keys`` for priority updates, ``weights`` for importance sampling), or an error."""

    request_id: int
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    error: str = ""  #: non-empty when no batch could be served (e.g. rate limiter timed out)
    info: dict[str, float] = field(default_factory=dict)  #: replay size, samples per insert, ...


@dataclass
class PriorityUpdate:
    """New priorities for sampled items; ``keys`` let the server ignore items since overwritten."""

    indices: np.ndarray  #: int64 [B] slots as sampled
    keys: np.ndarray  #: int64 [B] item keys as sampled
    priorities: np.ndarray  #: float32 [B], already raised to the PER exponent


Message = Union[Episode, EpisodeAck, WeightsUpdate, Status, SampleRequest, SampleBatch, PriorityUpdate]


def encode(message: Message) -> bytes:
    """Serialise any message (validating an episode first, so bad data never leaves)."""
    if isinstance(message, Episode):
        validate_episode(message)
        fields = {
            "actor_id": message.actor_id,
            "episode_id": message.episode_id,
            "task": message.task,
            "seed": message.seed,
            "is_demo": message.is_demo,
            "success": message.success,
            "timeout": message.timeout,
            "info": message.info,
        }
        arrays = {f"obs/{k}": v for k, v in message.observations.items()}
        arrays |= {
            "step/actions": message.actions,
            "step/rewards": message.rewards,
            "step/terminals": message.terminals,
            "step/policy_versions": message.policy_versions,
        }
        return encode_frame(Kind.EPISODE, fields, arrays)
    if isinstance(message, EpisodeAck):
        fields = {
            "actor_id": message.actor_id,
            "episode_id": message.episode_id,
            "status": AckStatus(message.status).value,
            "reason": message.reason,
        }
        return encode_frame(Kind.ACK, fields, {})
    if isinstance(message, WeightsUpdate):
        fields = {
            "version": message.version,
            "learner_step": message.learner_step,
            "config_digest": message.config_digest,
            "published_at": message.published_at,
            "env_steps": message.env_steps,
        }
        return encode_frame(Kind.WEIGHTS, fields, message.tensors)
    if isinstance(message, Status):
        fields = {k: getattr(message, k) for k in Status.__dataclass_fields__}
        return encode_frame(Kind.STATUS, fields, {})
    if isinstance(message, SampleRequest):
        fields = {k: getattr(message, k) for k in SampleRequest.__dataclass_fields__}
        return encode_frame(Kind.SAMPLE_REQUEST, fields, {})
    if isinstance(message, SampleBatch):
        fields = {"request_id": message.request_id, "error": message.error, "info": message.info}
        return encode_frame(Kind.SAMPLE_BATCH, fields, message.arrays)
    if isinstance(message, PriorityUpdate):
        arrays = {"indices": message.indices, "keys": message.keys, "priorities": message.priorities}
        return encode_frame(Kind.PRIORITY_UPDATE, {}, arrays)
    raise TypeError(f"not a protocol message: {type(message).__name__}")


def decode(data: bytes, expect: type | None = None, max_bytes: int = DEFAULT_MAX_BYTES) -> Message:
    """Parse and validate one message; ``expect`` rejects a valid message of another kind."""
    kind, fields, arrays = decode_frame(data, max_bytes)
    try:
        kind = Kind(kind)
    except ValueError:
        raise ProtocolError("frame.kind", f"unknown message kind {kind}") from None
    decoder = _DECODERS[kind]
    if expect is not None and decoder[0] is not expect:
        raise ProtocolError("frame.kind", f"expected {expect.__name__}, got {decoder[0].__name__}")
    return decoder[1](fields, arrays)


def _decode_episode(fields, arrays) -> Episode:
    steps = {k[len("step/") :]: v for k, v in arrays.items() if k.startswith("step/")}
    for name in ("actions", "rewards", "terminals", "policy_versions"):
        if name not in steps:
            raise ProtocolError(name, "missing")
    info = require(fields, "info", dict)
    if not all(isinstance(k, str) and isinstance(v, str) for k, v in info.items()):
        raise ProtocolError("info", "must map strings to strings")
    episode = Episode(
        actor_id=require(fields, "actor_id", str),
        episode_id=require(fields, "episode_id", int),
        task=require(fields, "task", str),
        seed=require(fields, "seed", int),
        is_demo=require(fields, "is_demo", bool),
        success=require(fields, "success", bool),
        timeout=require(fields, "timeout", bool),
        observations={k[len("obs/") :]: v for k, v in arrays.items() if k.startswith("obs/")},
        actions=steps["actions"],
        rewards=steps["rewards"],
        terminals=steps["terminals"],
        policy_versions=steps["policy_versions"],
        info=info,
    )
    unexpected = [k for k in arrays if not k.startswith(("obs/", "step/"))]
    if unexpected:
        raise ProtocolError(unexpected[0], "unknown array in an episode")
    validate_episode(episode)
    return episode


def _decode_ack(fields, arrays) -> EpisodeAck:
    status = require(fields, "status", str)
    try:
        status = AckStatus(status)
    except ValueError:
        raise ProtocolError("status", f"unknown ack status {status!r}") from None
    return EpisodeAck(
        actor_id=require(fields, "actor_id", str),
        episode_id=require(fields, "episode_id", int),
        status=status,
        reason=require(fields, "reason", str),
    )


def _decode_weights(fields, arrays) -> WeightsUpdate:
    for name, array in arrays.items():
        if array.dtype.kind != "f":
            raise ProtocolError(f"tensors.{name}", f"dtype {array.dtype}; weights are floating point")
    return WeightsUpdate(
        version=require(fields, "version", int),
        learner_step=require(fields, "learner_step", int),
        tensors=arrays,
        config_digest=require(fields, "config_digest", str),
        published_at=float(require(fields, "published_at", (int, float))),
        env_steps=require(fields, "env_steps", int),
    )


def _decode_status(fields, arrays) -> Status:
    counters = require(fields, "counters", dict)
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in counters.values()):
        raise ProtocolError("counters", "values must be numbers")
    info = require(fields, "info", dict)
    if not all(isinstance(v, str) for v in info.values()):
        raise ProtocolError("info", "values must be strings")
    return Status(
        role=require(fields, "role", str),
        instance=require(fields, "instance", str),
        run_id=require(fields, "run_id", str),
        pid=require(fields, "pid", int),
        host=require(fields, "host", str),
        time=float(require(fields, "time", (int, float))),
        state=require(fields, "state", str),
        counters={k: float(v) for k, v in counters.items()},
        info=info,
    )


def _decode_sample_request(fields, arrays) -> SampleRequest:
    request = SampleRequest(
        request_id=require(fields, "request_id", int),
        batch_size=require(fields, "batch_size", int),
        timeout_ms=require(fields, "timeout_ms", int),
    )
    if not 1 <= request.batch_size <= 65536:
        raise ProtocolError("batch_size", f"{request.batch_size} is outside 1..65536")
    if request.timeout_ms < 0:
        raise ProtocolError("timeout_ms", "must be >= 0")
    return request


def _decode_sample_batch(fields, arrays) -> SampleBatch:
    info = require(fields, "info", dict)
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in info.values()):
        raise ProtocolError("info", "values must be numbers")
    return SampleBatch(
        request_id=require(fields, "request_id", int),
        arrays=arrays,
        error=require(fields, "error", str),
        info={k: float(v) for k, v in info.items()},
    )


def _decode_priority_update(fields, arrays) -> PriorityUpdate:
    for name, dtype in (("indices", "int64"), ("keys", "int64"), ("priorities", "float32")):
        if name not in arrays:
            raise ProtocolError(name, "missing")
        if arrays[name].dtype.name != dtype or arrays[name].ndim != 1:
            raise ProtocolError(name, f"expected a 1-D {dtype} array, got {arrays[name].dtype}{list(arrays[name].shape)}")
    if not arrays["indices"].shape == arrays["keys"].shape == arrays["priorities"].shape:
        raise ProtocolError("priorities", "indices, keys and priorities must have one length")
    if not np.isfinite(arrays["priorities"]).all() or (arrays["priorities"] < 0).any():
        raise ProtocolError("priorities", "must be finite and >= 0")
    return PriorityUpdate(arrays["indices"], arrays["keys"], arrays["priorities"])


_DECODERS = {
    Kind.EPISODE: (Episode, _decode_episode),
    Kind.ACK: (EpisodeAck, _decode_ack),
    Kind.WEIGHTS: (WeightsUpdate, _decode_weights),
    Kind.STATUS: (Status, _decode_status),
    Kind.SAMPLE_REQUEST: (SampleRequest, _decode_sample_request),
    Kind.SAMPLE_BATCH: (SampleBatch, _decode_sample_batch),
    Kind.PRIORITY_UPDATE: (PriorityUpdate, _decode_priority_update),
}
