"""Property: every decode entry point returns a valid message or raises ProtocolError, never
anything else, whatever arrives: random bytes, or valid frames of every message type with
bytes flipped, inserted, deleted or cut, and with their JSON header edited (wrong dtypes,
shapes and offsets, deep nesting, NaN, wildcard ids, huge integers, unknown fields).

A message that is accepted must also be sane on its own: ids key-safe, integers in
0..2**53-1, floats finite outside point clouds, and it must encode again.
"""

from __future__ import annotations

import json
import math
import re
import struct

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from synthetic_episodes import synthetic_episode

from protocol import (
    MAX_INT,
    AckStatus,
    Episode,
    EpisodeAck,
    PriorityUpdate,
    ProtocolError,
    SampleBatch,
    SampleRequest,
    Status,
    WeightsUpdate,
    decode,
    encode,
    validate,
)
from protocol.codec import MAGIC, PROTOCOL_VERSION, decode_frame, peek_fields
from protocol.episode import is_point_cloud
from protocol.messages import Kind

FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def small_episode() -> Episode:
    episode = synthetic_episode(steps=2, size=4)
    n = 3
    episode.observations["front_points"][0, 0, 0] = np.nan  # allowed: invalid depth
    episode.observations["extra_voxel_indices"] = np.ones((n, 2, 3), np.int64)
    episode.observations["extra_attention_coordinates"] = np.zeros((n, 2, 3), np.float32)
    episode.observations["extra_rot_grip_indices"] = np.ones((n, 4), np.int64)
    return episode


MESSAGES = [
    small_episode(),
    EpisodeAck("actor-0", 3, AckStatus.REJECTED, "bad depth", "0123456789abcdef"),
    WeightsUpdate(
        2, 10, {"a.weight": np.ones((2, 3), np.float32), "a.bias": np.zeros(2, np.float16)}, "abc123", 1.7e9, 5
    ),
    Status(
        "learner", "learner-0", "run-1", 42, "host", 1.7e9, "running", {"loss/td": float("nan"), "n": 3}, {"k": "v"}
    ),
    SampleRequest(7, 32, 500),
    SampleBatch(
        7,
        {
            "front_points": np.full((2, 3), np.nan, np.float16),
            "reward": np.ones(2, np.float32),
            "terminal": np.array([True, False]),
        },
        "",
        {"replay_size": 10.0},
    ),
    SampleBatch(8, {}, "rate limiter timed out", {}),
    PriorityUpdate(np.arange(4, dtype=np.int64), np.arange(4, dtype=np.int64), np.ones(4, np.float32)),
]
VALID = [encode(m) for m in MESSAGES]
ID_FIELDS = ("actor_id", "task", "role", "instance", "run_id", "state")
INT_FIELDS = (
    "episode_id",
    "seed",
    "version",
    "learner_step",
    "env_steps",
    "pid",
    "request_id",
    "batch_size",
    "timeout_ms",
)
SAFE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}")


def assert_sane(message) -> None:
    """Independent checks of what decode let through (not a second call of its validator)."""
    for name in ID_FIELDS:
        if hasattr(message, name):
            assert SAFE_ID.fullmatch(getattr(message, name)), name
    for name in INT_FIELDS:
        if hasattr(message, name):
            value = getattr(message, name)
            assert type(value) is int and 0 <= value <= MAX_INT, name
    arrays = {}
    if isinstance(message, Episode):
        arrays = {**message.observations, "actions": message.actions, "rewards": message.rewards}
    elif isinstance(message, WeightsUpdate):
        arrays = message.tensors
    elif isinstance(message, SampleBatch):
        arrays = message.arrays
    elif isinstance(message, PriorityUpdate):
        arrays = {"priorities": message.priorities}
        assert (message.priorities >= 0).all()
    for name, array in arrays.items():
        if array.dtype.kind == "f" and not is_point_cloud(name):
            assert np.isfinite(array).all(), name
        if array.dtype == np.bool_:
            assert array.view(np.uint8).max(initial=0) <= 1, name
    validate(message)
    encode(message)


def receive(data, **kwargs):
    """What a receiver does: decode, or get a ProtocolError. Anything else fails the test."""
    try:
        message = decode(data, **kwargs)
    except ProtocolError as exc:
        assert exc.field and exc.reason
        return exc
    assert_sane(message)
    return message


def every_entry_point(data) -> None:
    """decode (any kind and each expected kind), decode_frame and peek_fields."""
    receive(data)
    for cls in (Episode, EpisodeAck, WeightsUpdate, Status, SampleRequest, SampleBatch, PriorityUpdate):
        receive(data, expect=cls)
    for entry in (decode_frame, peek_fields):
        try:
            entry(data)
        except ProtocolError:
            pass


# -- (a) random bytes ------------------------------------------------------------------------


@FAST
@given(st.binary(max_size=4096))
def test_random_bytes(data):
    every_entry_point(data)


@FAST
@given(st.sampled_from(list(Kind)), st.binary(max_size=2048))
def test_random_bodies_behind_a_valid_frame_header(kind, body):
    every_entry_point(struct.pack("<4sHH", MAGIC, PROTOCOL_VERSION, kind) + body)


# -- (b) byte-level mutations of valid frames ------------------------------------------------


@FAST
@given(st.sampled_from(VALID), st.data())
def test_flipped_inserted_deleted_and_truncated_bytes(data, draw):
    frame = bytearray(data)
    for _ in range(draw.draw(st.integers(1, 6))):
        op = draw.draw(st.sampled_from(["flip", "set", "insert", "delete", "truncate"]))
        at = draw.draw(st.integers(0, max(0, len(frame) - 1)))
        if op == "flip" and frame:
            frame[at] ^= 1 << draw.draw(st.integers(0, 7))
        elif op == "set" and frame:
            frame[at] = draw.draw(st.integers(0, 255))
        elif op == "insert":
            frame[at:at] = draw.draw(st.binary(min_size=1, max_size=16))
        elif op == "delete":
            del frame[at : at + draw.draw(st.integers(1, 16))]
        elif op == "truncate":
            del frame[at:]
    every_entry_point(bytes(frame))


@FAST
@given(st.sampled_from(VALID), st.integers(0, 2**64 - 1))
def test_a_lying_header_length(data, length):
    every_entry_point(data[:8] + struct.pack("<Q", length) + data[16:])


# -- (b) structured edits of the JSON header --------------------------------------------------


def split(data: bytes) -> tuple[int, dict, dict, bytes]:
    """A valid frame -> (kind, fields, array table, array bytes)."""
    (n,) = struct.unpack_from("<Q", data, 8)
    header = json.loads(data[16 : 16 + n])
    fields = json.loads(header.pop("__metadata__")["fields"])
    return struct.unpack_from("<H", data, 6)[0], fields, header, data[16 + n :]


def join(kind: int, fields, table: dict, buffers: bytes, raw_fields: str | None = None) -> bytes:
    header = {"__metadata__": {"fields": raw_fields if raw_fields is not None else json.dumps(fields)}, **table}
    text = json.dumps(header).encode()
    return struct.pack("<4sHHQ", MAGIC, PROTOCOL_VERSION, kind, len(text)) + text + buffers


def nested(depth: int):
    value: object = 0
    for _ in range(depth):
        value = [value]
    return value


hostile_values = st.one_of(
    st.sampled_from([
        math.nan, math.inf, -math.inf, -1, 0, 1, MAX_INT, MAX_INT + 1, 2**63, 10**16, True, False, None, 1.5,
        "", "*", "**", "a/b", "$*", "a b", "a\n", "x" * 65, "actor-0", "\ud800", [], {}, {"a": math.nan},
        "stored", "F32", [1, 2], -0.0, 1e308,
    ]),
    st.integers(0, 64).map(nested),
    st.text(max_size=12),
    st.integers(),
    st.floats(),
)
DTYPES = ["U8", "BOOL", "I32", "I64", "F16", "F32", "F64", "BF16", "U16", "I8", "U64", "C64", "F8_E4M3", "f32", ""]


@st.composite
def edited_frames(draw):
    kind, fields, table, buffers = split(draw(st.sampled_from(VALID)))
    raw_fields = None
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["set", "add", "drop", "dtype", "shape", "offsets", "entry", "raw", "kind", "nan"]))
        names = sorted(n for n, entry in table.items() if isinstance(entry, dict))
        if op == "set" and fields:
            fields[draw(st.sampled_from(sorted(fields)))] = draw(hostile_values)
        elif op == "add":
            fields[draw(st.sampled_from(["x", "info", "counters", "actor_id", "arrays"]))] = draw(hostile_values)
        elif op == "drop" and fields:
            del fields[draw(st.sampled_from(sorted(fields)))]
        elif op == "dtype" and names:
            table[draw(st.sampled_from(names))]["dtype"] = draw(st.sampled_from(DTYPES))
        elif op == "shape" and names:
            table[draw(st.sampled_from(names))]["shape"] = draw(
                st.lists(st.one_of(st.integers(-2, 8), st.sampled_from([2**31, 2**40, 2**63])), max_size=9)
                | hostile_values
            )
        elif op == "offsets" and names:
            table[draw(st.sampled_from(names))]["data_offsets"] = draw(
                st.lists(st.integers(-2, len(buffers) + 8), min_size=0, max_size=3) | hostile_values
            )
        elif op == "entry":
            name = draw(st.sampled_from(sorted(table) + ["obs/extra_x", "step/actions", "w", "a*b", "", "x" * 300]))
            if table and draw(st.booleans()):
                table.pop(name, None)
            else:
                table[name] = draw(hostile_values | st.just({"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}))
        elif op == "raw":
            raw_fields = draw(st.sampled_from(["", "{", "[]", "null", '{"a":1,"a":2}', "[" * 5000, "NaN"])
                              | st.text(max_size=30))
        elif op == "kind":
            kind = draw(st.integers(0, 9))
        elif op == "nan":
            fields = {k: (math.nan if isinstance(v, float) else v) for k, v in fields.items()}
    try:
        return join(kind, fields, table, buffers, raw_fields)
    except (TypeError, ValueError):  # e.g. a surrogate json.dumps cannot write as UTF-8
        return join(kind, {}, table, buffers)


@FAST
@given(edited_frames())
def test_edited_json_headers(data):
    every_entry_point(data)


# -- (b) hostile array values: NaN, infinities and bool bytes inside valid frames -------------

NAN_BYTES = {"float16": b"\x00\x7e", "float32": b"\x00\x00\xc0\x7f", "float64": b"\x00" * 6 + b"\xf8\x7f"}
INF_BYTES = {"float16": b"\x00\x7c", "float32": b"\x00\x00\x80\x7f", "float64": b"\x00" * 6 + b"\xf0\x7f"}
DTYPE_OF = {"F16": "float16", "F32": "float32", "F64": "float64", "BOOL": "bool"}


@FAST
@given(st.sampled_from(VALID), st.data())
def test_nan_inside_an_array_is_refused_unless_it_is_a_point_cloud(data, draw):
    kind, fields, table, buffers = split(data)
    targets = sorted(
        n for n, e in table.items() if e["dtype"] in DTYPE_OF and e["data_offsets"][1] > e["data_offsets"][0]
    )
    if not targets:
        return
    name = draw.draw(st.sampled_from(targets))
    dtype = DTYPE_OF[table[name]["dtype"]]
    begin, end = table[name]["data_offsets"]
    size = np.dtype(dtype).itemsize
    at = begin + size * draw.draw(st.integers(0, (end - begin) // size - 1))
    value = b"\x02" if dtype == "bool" else draw.draw(st.sampled_from([NAN_BYTES, INF_BYTES]))[dtype]
    poisoned = buffers[:at] + value + buffers[at + size :]
    result = receive(join(kind, fields, table, poisoned))
    if not is_point_cloud(name.split("/")[-1]):
        assert isinstance(result, ProtocolError), f"{name}: a poisoned value was accepted"


# -- hostile field values built from scratch --------------------------------------------------


@FAST
@given(
    st.sampled_from(list(Kind)),
    st.dictionaries(
        st.sampled_from(["actor_id", "episode_id", "status", "reason", "role", "instance", "run_id", "pid", "host",
                         "time", "state", "counters", "info", "version", "learner_step", "config_digest",
                         "published_at", "env_steps", "request_id", "batch_size", "timeout_ms", "error", "x"]),
        hostile_values,
        max_size=12,
    ),
)
def test_well_framed_fields_of_any_value(kind, fields):
    try:
        data = join(kind, fields, {}, b"")
    except (TypeError, ValueError):
        return
    every_entry_point(data)


def test_the_corpus_itself_is_valid():
    for data in VALID:
        assert not isinstance(receive(data), ProtocolError)
