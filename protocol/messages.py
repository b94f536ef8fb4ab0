"""Every message the roles exchange, and the one pair of functions that (de)serialise them.

``encode(message) -> bytes`` and ``decode(data, expect=...) -> message``. Decoding checks the
frame, the version, the kind and the schema, and raises :class:`ProtocolError` (naming the
field at fault) for anything else, never another exception; receivers count those and keep
serving. The schema is strict: unknown or missing fields, ids outside the key-safe charset,
integers outside 0..2**53-1, non-finite numbers (except point clouds and diagnostic
counters) and anything beyond :class:`protocol.limits.Limits` are refused.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Union

import numpy as np

from protocol import keys
from protocol.codec import (
    DIGEST_PATTERN,
    WIRE_DTYPES,
    ProtocolError,
    check_array_values,
    check_float,
    check_int,
    check_keys,
    check_map,
    check_name,
    check_text,
    decode_frame,
    encode_frame,
    require,
)
from protocol.episode import Episode, is_point_cloud, validate_episode
from protocol.limits import DEFAULT_LIMITS, Limits


class Kind(enum.IntEnum):
    EPISODE = 1
    ACK = 2
    WEIGHTS = 3
    STATUS = 4
    SAMPLE_REQUEST = 5
    SAMPLE_BATCH = 6
    PRIORITY_UPDATE = 7
    OPERATOR = 8


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
    digest: str = ""  #: payload_digest of the episode bytes this answers: only that exact payload is retired


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


class OperatorAction(str, enum.Enum):
    """What the person beside a real robot can say."""

    SUCCESS = "success"  #: the task is done: reward, end the episode
    FAIL = "fail"  #: the task went wrong: end the episode without reward
    RESET_DONE = "reset_done"  #: the scene is set up again: the next episode may start
    STOP = "stop"  #: halt the arm at once and pause the actor
    RESUME = "resume"  #: the actor may move the arm again


@dataclass
class OperatorCommand:
    """A person's word to one robot actor (dashboard button or terminal key)."""

    actor: str  #: the robot actor's instance name
    action: OperatorAction
    seq: int = 0  #: the sender's running number, for the actor's log
    time: float = 0.0  #: sender's wall clock, seconds since the epoch
    source: str = ""  #: where it came from, e.g. "dashboard" or "terminal"


Message = Union[Episode, EpisodeAck, WeightsUpdate, Status, SampleRequest, SampleBatch, PriorityUpdate, OperatorCommand]


def encode(message: Message, limits: Limits = DEFAULT_LIMITS) -> bytes:
    """Serialise any message after the checks ``decode`` applies, so what leaves decodes
    (a sender finds its own bug, not every receiver). Raises :class:`ProtocolError`."""
    validate(message, limits)
    return encode_unchecked(message)


def encode_unchecked(message: Message) -> bytes:
    """Serialise without any check, as a buggy or hostile sender would (e.g. NaN rewards):
    only for tests and benches that attack the receivers. Everything shipped uses ``encode``."""
    if isinstance(message, Episode):
        fields = {name: getattr(message, name) for name in _EPISODE_FIELDS}
        arrays = {f"obs/{k}": v for k, v in message.observations.items()}
        arrays |= {f"step/{name}": getattr(message, name) for name in _STEP_ARRAYS}
        return encode_frame(Kind.EPISODE, fields, arrays)
    if isinstance(message, EpisodeAck):
        fields = {
            "actor_id": message.actor_id,
            "episode_id": message.episode_id,
            "status": AckStatus(message.status).value,
            "reason": message.reason,
            "digest": message.digest,
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
    if isinstance(message, OperatorCommand):
        fields = {k: getattr(message, k) for k in OperatorCommand.__dataclass_fields__}
        fields["action"] = getattr(message.action, "value", message.action)
        return encode_frame(Kind.OPERATOR, fields, {})
    arrays = {"indices": message.indices, "keys": message.keys, "priorities": message.priorities}
    return encode_frame(Kind.PRIORITY_UPDATE, {}, arrays)


def decode(
    data: bytes, expect: type | None = None, max_bytes: int | None = None, limits: Limits = DEFAULT_LIMITS
) -> Message:
    """Parse and validate one message; ``expect`` rejects a valid message of another kind.

    Raises :class:`ProtocolError` and nothing else, whatever ``data`` holds. ``max_bytes``
    (default ``limits.max_bytes``) bounds the message; ``limits`` carries the receiver's
    other ceilings (steps, cameras, batch size, ...).
    """
    try:
        kind, fields, arrays = decode_frame(data, max_bytes, limits)
        try:
            kind = Kind(kind)
        except ValueError:
            raise ProtocolError("frame.kind", f"unknown message kind {kind}") from None
        cls, build = _DECODERS[kind]
        if expect is not None and cls is not expect:
            raise ProtocolError("frame.kind", f"expected {expect.__name__}, got {cls.__name__}")
        message = build(fields, arrays, limits)
        validate(message, limits)
        return message
    except ProtocolError:
        raise
    except Exception as exc:  # last resort: a receiver must only ever see ProtocolError
        raise ProtocolError("message", f"cannot be decoded ({type(exc).__name__}: {str(exc)[:200]})") from None


def validate(message: Message, limits: Limits = DEFAULT_LIMITS) -> None:
    """Raise :class:`ProtocolError` naming the first field of ``message`` that breaks its schema."""
    for cls, check in _VALIDATORS:
        if isinstance(message, cls):
            return check(message, limits)
    raise TypeError(f"not a protocol message: {type(message).__name__}")


# -- per-message schemas -------------------------------------------------------------------


def _check_id(name: str, value) -> str:
    if not keys.is_valid_id(value):
        shown = repr(value[:80]) if isinstance(value, str) else type(value).__name__
        raise ProtocolError(name, f"invalid id {shown}: use 1-{keys.MAX_ID_LENGTH} letters, digits, '_', '.', '-'")
    return value


def _no_arrays(arrays: dict) -> None:
    if arrays:
        raise ProtocolError(next(iter(arrays)), "unexpected array: this message carries none")


def _check_arrays(name: str, arrays, limits: Limits, dtypes=WIRE_DTYPES, finite=lambda n: True) -> None:
    """A dict of named arrays: count, names, dtypes, dimensions, and values (see check_array_values)."""
    if not isinstance(arrays, dict):
        raise ProtocolError(name, f"expected a dict of arrays, got {type(arrays).__name__}")
    if len(arrays) > limits.max_arrays:
        raise ProtocolError(name, f"{len(arrays)} arrays exceeds the limit of {limits.max_arrays}")
    for key, array in arrays.items():
        where = f"{name}.{check_name(key, name, limits)}"
        if not isinstance(array, np.ndarray) or array.dtype not in dtypes:
            got = getattr(array, "dtype", type(array).__name__)
            raise ProtocolError(where, f"dtype {got}, expected one of {sorted(d.name for d in dtypes)}")
        if array.ndim > limits.max_ndim:
            raise ProtocolError(where, f"{array.ndim} dimensions exceeds the limit of {limits.max_ndim}")
        check_array_values(where, array, finite=finite(key))


_FLOAT_DTYPES = frozenset(d for d in WIRE_DTYPES if d.kind == "f")


def _validate_ack(m: EpisodeAck, limits: Limits) -> None:
    _check_id("actor_id", m.actor_id)
    check_int("episode_id", m.episode_id)
    try:
        AckStatus(m.status)
    except (ValueError, TypeError):
        raise ProtocolError("status", f"unknown ack status {m.status!r:.80}") from None
    check_text("reason", m.reason, limits.max_text)
    if not isinstance(m.digest, str) or not DIGEST_PATTERN.fullmatch(m.digest):
        raise ProtocolError("digest", "an ack names its episode's payload digest (16 hex digits)")


def _validate_weights(m: WeightsUpdate, limits: Limits) -> None:
    check_int("version", m.version)
    check_int("learner_step", m.learner_step)
    check_int("env_steps", m.env_steps)
    if m.config_digest != "":
        _check_id("config_digest", m.config_digest)
    check_float("published_at", m.published_at, lo=0.0)
    # Weights are floating point and finite: one NaN would make every action NaN.
    _check_arrays("tensors", m.tensors, limits, dtypes=_FLOAT_DTYPES)


def _validate_status(m: Status, limits: Limits) -> None:
    _check_id("role", m.role)
    _check_id("instance", m.instance)
    _check_id("run_id", m.run_id)
    check_int("pid", m.pid, 0, 2**32)
    check_text("host", m.host, 255)
    check_float("time", m.time, lo=0.0)
    _check_id("state", m.state)
    # Counters may be NaN or infinite: a diverged loss is exactly what the dashboard must show
    # (it renders them as null), and refusing the whole heartbeat would hide the role instead.
    check_map("counters", m.counters, limits, "any-number")
    check_map("info", m.info, limits, "text")


def _validate_sample_request(m: SampleRequest, limits: Limits) -> None:
    check_int("request_id", m.request_id)
    check_int("batch_size", m.batch_size, 1, limits.max_batch)
    check_int("timeout_ms", m.timeout_ms, 0, limits.max_timeout_ms)


def _validate_sample_batch(m: SampleBatch, limits: Limits) -> None:
    check_int("request_id", m.request_id)
    check_text("error", m.error, limits.max_text)
    check_map("info", m.info, limits, "any-number")  # diagnostics, logged, never trained on
    _check_arrays("arrays", m.arrays, limits, finite=lambda name: not is_point_cloud(name))


def _validate_priority_update(m: PriorityUpdate, limits: Limits) -> None:
    for name, dtype in (("indices", "int64"), ("keys", "int64"), ("priorities", "float32")):
        array = getattr(m, name)
        if not isinstance(array, np.ndarray) or array.dtype != np.dtype(dtype) or array.ndim != 1:
            got = f"{array.dtype}{list(array.shape)}" if isinstance(array, np.ndarray) else type(array).__name__
            raise ProtocolError(name, f"expected a 1-D {dtype} array, got {got}")
    if not m.indices.shape == m.keys.shape == m.priorities.shape:
        raise ProtocolError("priorities", "indices, keys and priorities must have one length")
    if m.priorities.shape[0] > limits.max_priorities:
        raise ProtocolError(
            "priorities", f"{m.priorities.shape[0]} entries exceeds the limit of {limits.max_priorities}"
        )
    if m.indices.size and (m.indices.min() < 0 or m.keys.min() < 0):
        raise ProtocolError("indices", "indices and keys must be >= 0")
    if not np.isfinite(m.priorities).all() or (m.priorities < 0).any():
        raise ProtocolError("priorities", "must be finite and >= 0")


def _validate_operator(m: OperatorCommand, limits: Limits) -> None:
    _check_id("actor", m.actor)
    try:
        OperatorAction(m.action)
    except (ValueError, TypeError):
        raise ProtocolError("action", f"unknown operator action {m.action!r:.80}") from None
    check_int("seq", m.seq)
    check_float("time", m.time, lo=0.0)
    check_text("source", m.source, limits.max_text)


_VALIDATORS = (
    (Episode, validate_episode),
    (EpisodeAck, _validate_ack),
    (WeightsUpdate, _validate_weights),
    (Status, _validate_status),
    (SampleRequest, _validate_sample_request),
    (SampleBatch, _validate_sample_batch),
    (PriorityUpdate, _validate_priority_update),
    (OperatorCommand, _validate_operator),
)


# -- decoders: fields and arrays -> message (validated afterwards) ----------------------------

_EPISODE_FIELDS = ("actor_id", "episode_id", "task", "seed", "is_demo", "success", "timeout", "info")
_STEP_ARRAYS = ("actions", "rewards", "terminals", "policy_versions")


def _decode_episode(fields, arrays, limits) -> Episode:
    check_keys(fields, _EPISODE_FIELDS)
    unexpected = [k for k in arrays if not k.startswith(("obs/", "step/"))]
    if unexpected:
        raise ProtocolError(unexpected[0], "unknown array in an episode")
    steps = {k[len("step/") :]: v for k, v in arrays.items() if k.startswith("step/")}
    check_keys(steps, _STEP_ARRAYS, what="step/")
    return Episode(
        **{name: fields[name] for name in _EPISODE_FIELDS},
        observations={k[len("obs/") :]: v for k, v in arrays.items() if k.startswith("obs/")},
        **steps,
    )


def _decode_ack(fields, arrays, limits) -> EpisodeAck:
    check_keys(fields, ("actor_id", "episode_id", "status", "reason", "digest"))
    _no_arrays(arrays)
    status = require(fields, "status", str)
    try:
        status = AckStatus(status)
    except ValueError:
        raise ProtocolError("status", f"unknown ack status {status[:80]!r}") from None
    return EpisodeAck(fields["actor_id"], fields["episode_id"], status, fields["reason"], fields["digest"])


def _decode_weights(fields, arrays, limits) -> WeightsUpdate:
    check_keys(fields, ("version", "learner_step", "config_digest", "published_at", "env_steps"))
    return WeightsUpdate(
        version=fields["version"],
        learner_step=fields["learner_step"],
        tensors=arrays,
        config_digest=fields["config_digest"],
        published_at=check_float("published_at", fields["published_at"], lo=0.0),
        env_steps=fields["env_steps"],
    )


def _decode_status(fields, arrays, limits) -> Status:
    check_keys(fields, tuple(Status.__dataclass_fields__))
    _no_arrays(arrays)
    values = dict(fields)
    values["time"] = check_float("time", fields["time"], lo=0.0)
    values["counters"] = check_map("counters", fields["counters"], limits, "any-number")
    return Status(**values)


def _decode_sample_request(fields, arrays, limits) -> SampleRequest:
    check_keys(fields, tuple(SampleRequest.__dataclass_fields__))
    _no_arrays(arrays)
    return SampleRequest(**fields)


def _decode_sample_batch(fields, arrays, limits) -> SampleBatch:
    check_keys(fields, ("request_id", "error", "info"))
    info = check_map("info", fields["info"], limits, "any-number")
    return SampleBatch(request_id=fields["request_id"], arrays=arrays, error=fields["error"], info=info)


def _decode_priority_update(fields, arrays, limits) -> PriorityUpdate:
    check_keys(fields, ())
    check_keys(arrays, ("indices", "keys", "priorities"))
    return PriorityUpdate(arrays["indices"], arrays["keys"], arrays["priorities"])


def _decode_operator(fields, arrays, limits) -> OperatorCommand:
    check_keys(fields, tuple(OperatorCommand.__dataclass_fields__))
    _no_arrays(arrays)
    action = require(fields, "action", str)
    try:
        action = OperatorAction(action)
    except ValueError:
        raise ProtocolError("action", f"unknown operator action {action[:80]!r}") from None
    return OperatorCommand(fields["actor"], action, fields["seq"], check_float("time", fields["time"], lo=0.0),
                           fields["source"])


_DECODERS = {
    Kind.EPISODE: (Episode, _decode_episode),
    Kind.ACK: (EpisodeAck, _decode_ack),
    Kind.WEIGHTS: (WeightsUpdate, _decode_weights),
    Kind.STATUS: (Status, _decode_status),
    Kind.SAMPLE_REQUEST: (SampleRequest, _decode_sample_request),
    Kind.SAMPLE_BATCH: (SampleBatch, _decode_sample_batch),
    Kind.PRIORITY_UPDATE: (PriorityUpdate, _decode_priority_update),
    Kind.OPERATOR: (OperatorCommand, _decode_operator),
}
