"""Every message type survives encode -> decode exactly, large episodes included."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_same_message, make_episode
from protocol import (
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
)
from protocol.observation import CAMERA_NAMES


def _messages():
    rng = np.random.default_rng(1)
    return [
        make_episode(),
        EpisodeAck("actor-3", 17, AckStatus.DUPLICATE, "already stored"),
        EpisodeAck("actor-3", 18, AckStatus.STORED),
        WeightsUpdate(
            version=5,
            learner_step=1200,
            tensors={
                "depth0.encoder.weight": rng.standard_normal((64, 10, 3, 3, 3)).astype(np.float32),
                "depth0.head.bias": rng.standard_normal(128).astype(np.float16),
            },
            config_digest="abc123",
        ),
        Status("actor", "actor-1", "run-1", 4242, "host-a", 1.7e9, "running", {"episodes": 3.0}, {"task": "reach"}),
        SampleRequest(request_id=9, batch_size=128, timeout_ms=500),
        SampleBatch(
            request_id=9,
            arrays={
                "front_rgb": rng.integers(0, 256, (4, 128, 128, 3), dtype=np.uint8),
                "indices": np.arange(4, dtype=np.int64),
                "weights": np.ones(4, dtype=np.float32),
            },
            info={"replay_size": 1000.0},
        ),
        SampleBatch(request_id=10, error="rate limiter timed out"),
        PriorityUpdate(
            indices=np.arange(5, dtype=np.int64),
            keys=np.arange(100, 105, dtype=np.int64),
            priorities=np.linspace(0.1, 1.0, 5).astype(np.float32),
        ),
    ]


@pytest.mark.parametrize("message", _messages(), ids=lambda m: type(m).__name__)
def test_every_message_round_trips(message):
    data = encode(message)
    assert isinstance(data, bytes)
    back = decode(data, expect=type(message))
    assert_same_message(message, back)


@pytest.mark.parametrize("cameras", [("front",), CAMERA_NAMES], ids=["1-camera", "4-cameras"])
def test_large_episodes_round_trip(cameras):
    episode = make_episode(cameras=cameras, steps=10, side=128)
    data = encode(episode)
    assert len(data) > len(cameras) * 11 * 128 * 128 * 9  # rgb (3 B) + float16 points (6 B) per pixel
    back = decode(data, expect=Episode)
    assert_same_message(episode, back)
    assert back.cameras == sorted(cameras)
    assert back.observation(10).step == 10


def test_a_many_megabyte_episode_round_trips():
    episode = make_episode(cameras=CAMERA_NAMES, steps=30, side=256)  # ~ 70 MB
    data = encode(episode)
    assert len(data) > 50 * 1024 * 1024
    assert_same_message(episode, decode(data))


def test_decode_rejects_a_valid_message_of_another_kind():
    data = encode(SampleRequest(request_id=1, batch_size=8))
    with pytest.raises(ProtocolError, match="expected Episode"):
        decode(data, expect=Episode)


def test_encode_refuses_an_invalid_episode_before_it_leaves():
    episode = make_episode()
    episode.rewards = episode.rewards[:-1]
    with pytest.raises(ProtocolError) as err:
        encode(episode)
    assert err.value.field == "rewards"


def test_decode_names_the_field_of_a_schema_violation():
    # A well-formed frame whose content breaks the schema, as a buggy or foreign sender makes.
    from protocol.codec import encode_frame
    from protocol.messages import Kind

    fields = {"role": "actor", "instance": "actor-0", "run_id": "r", "pid": "not a number", "host": "h",
              "time": 0.0, "state": "running", "counters": {}, "info": {}}
    with pytest.raises(ProtocolError) as err:
        decode(encode_frame(Kind.STATUS, fields, {}))
    assert err.value.field == "pid"

    episode = make_episode()
    episode.observations["front_points"] = episode.observations["front_points"][:, :64]
    arrays = {f"obs/{k}": v for k, v in episode.observations.items()}
    arrays |= {f"step/{k}": getattr(episode, k) for k in ("actions", "rewards", "terminals", "policy_versions")}
    fields = {"actor_id": "a", "episode_id": 0, "task": "t", "seed": 0, "is_demo": False, "success": True,
              "timeout": False, "info": {}}
    with pytest.raises(ProtocolError) as err:
        decode(encode_frame(Kind.EPISODE, fields, arrays))
    assert err.value.field == "observations.front_points"


def test_oversized_messages_are_rejected_before_parsing():
    data = encode(make_episode())
    with pytest.raises(ProtocolError, match="exceeds the limit"):
        decode(data, max_bytes=len(data) - 1)
    assert isinstance(decode(data, max_bytes=len(data)), Episode)
