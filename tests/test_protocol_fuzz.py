"""A receiver survives anything: truncated, oversized, wrong-version or random bytes.

``decode`` either returns a valid message or raises ProtocolError; no other exception
(and no crash) may escape, whatever arrives on the wire.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from synthetic_episodes import synthetic_episode

from protocol import PROTOCOL_VERSION, EpisodeAck, ProtocolError, SampleRequest, Status, decode, encode
from protocol.codec import MAGIC, encode_frame
from protocol.messages import AckStatus, Kind, PriorityUpdate

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])

SMALL_EPISODE = encode(synthetic_episode(steps=2, size=8))
VALID = [
    SMALL_EPISODE,
    encode(EpisodeAck("actor-0", 3, AckStatus.STORED, digest="0123456789abcdef")),
    encode(Status("actor", "actor-0", "run", 1, "h", 0.0)),
    encode(SampleRequest(1, 32)),
    encode(PriorityUpdate(np.arange(3), np.arange(3), np.ones(3, np.float32))),
]


def decode_safely(data: bytes, **kwargs):
    """What a receiver does: decode, or get a ProtocolError. Anything else fails the test."""
    try:
        return decode(data, **kwargs)
    except ProtocolError as exc:
        assert exc.field and exc.reason
        return exc


@FUZZ
@given(st.binary(max_size=4096))
def test_random_bytes_never_crash_the_receiver(data):
    assert isinstance(decode_safely(data), ProtocolError)  # random bytes are never a message


@FUZZ
@given(st.binary(max_size=2048))
def test_random_bodies_behind_a_valid_frame_header(body):
    for kind in Kind:
        decode_safely(struct.pack("<4sHH", MAGIC, PROTOCOL_VERSION, kind) + body)


@FUZZ
@given(st.sampled_from(VALID), st.data())
def test_truncated_messages_are_rejected(data, draw):
    cut = draw.draw(st.integers(0, len(data) - 1))
    assert isinstance(decode_safely(data[:cut]), ProtocolError)


@FUZZ
@given(st.sampled_from(VALID), st.data())
def test_corrupted_bytes_are_rejected_or_still_valid(data, draw):
    corrupted = bytearray(data)
    for _ in range(draw.draw(st.integers(1, 8))):
        at = draw.draw(st.integers(0, len(data) - 1))
        corrupted[at] = draw.draw(st.integers(0, 255))
    decode_safely(bytes(corrupted))


@FUZZ
@given(st.sampled_from(VALID), st.integers(0, 65535).filter(lambda v: v != PROTOCOL_VERSION))
def test_wrong_versions_are_rejected(data, version):
    wrong = data[:4] + struct.pack("<H", version) + data[6:]
    err = decode_safely(wrong)
    assert isinstance(err, ProtocolError) and err.field == "frame.version"


@FUZZ
@given(st.sampled_from(VALID), st.integers(0, 64))
def test_oversized_messages_are_rejected(data, slack):
    limit = max(0, len(data) - 1 - slack)
    err = decode_safely(data, max_bytes=limit)
    assert isinstance(err, ProtocolError) and err.field == "frame"


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3),
    max_leaves=8,
)


@FUZZ
@given(
    st.sampled_from(list(Kind)),
    st.dictionaries(st.sampled_from(["actor_id", "episode_id", "role", "status", "pid", "info", "counters",
                                     "version", "request_id", "batch_size", "x"]), json_values, max_size=8),
    st.dictionaries(
        st.sampled_from(["obs/front_rgb", "step/actions", "indices", "keys", "priorities", "w"]),
        st.sampled_from([np.zeros(3, np.int64), np.ones((2, 8), np.float32), np.zeros((0,), np.uint8),
                         np.full(3, np.nan, np.float32), np.zeros((1, 1, 1, 3), np.uint8)]),
        max_size=4,
    ),
)
def test_well_framed_nonsense_is_rejected_by_the_schema(kind, fields, arrays):
    decode_safely(encode_frame(kind, fields, arrays))


@pytest.mark.parametrize("data", VALID, ids=lambda d: f"{len(d)}B")
def test_the_fuzz_corpus_itself_is_valid(data):
    assert not isinstance(decode_safely(data), ProtocolError)
