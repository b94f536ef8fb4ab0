"""Every message type survives encode -> decode exactly, large episodes included."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_same_message
from synthetic_episodes import synthetic_episode

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

DIGEST = "0123456789abcdef"  #: an ack's payload digest (any 16 hex digits for the codec)


def _messages():
    rng = np.random.default_rng(1)
    return [
        synthetic_episode(),
        EpisodeAck("actor-3", 17, AckStatus.DUPLICATE, "already stored", DIGEST),
        EpisodeAck("actor-3", 18, AckStatus.STORED, digest=DIGEST),
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
    episode = synthetic_episode(cameras=cameras, steps=10, size=128)
    data = encode(episode)
    assert len(data) > len(cameras) * 11 * 128 * 128 * 9  # rgb (3 B) + float16 points (6 B) per pixel
    back = decode(data, expect=Episode)
    assert_same_message(episode, back)
    assert back.cameras == sorted(cameras)
    assert back.observation(10).step == 10


def test_a_many_megabyte_episode_round_trips():
    episode = synthetic_episode(cameras=CAMERA_NAMES, steps=30, size=256)  # ~ 70 MB
    data = encode(episode)
    assert len(data) > 50 * 1024 * 1024
    assert_same_message(episode, decode(data))


def test_decode_rejects_a_valid_message_of_another_kind():
    data = encode(SampleRequest(request_id=1, batch_size=8))
    with pytest.raises(ProtocolError, match="expected Episode"):
        decode(data, expect=Episode)


def test_encode_refuses_an_invalid_episode_before_it_leaves():
    episode = synthetic_episode()
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

    episode = synthetic_episode()
    episode.observations["front_points"] = episode.observations["front_points"][:, :64]
    arrays = {f"obs/{k}": v for k, v in episode.observations.items()}
    arrays |= {f"step/{k}": getattr(episode, k) for k in ("actions", "rewards", "terminals", "policy_versions")}
    fields = {"actor_id": "a", "episode_id": 0, "task": "t", "seed": 0, "is_demo": False, "success": True,
              "timeout": False, "info": {}}
    with pytest.raises(ProtocolError) as err:
        decode(encode_frame(Kind.EPISODE, fields, arrays))
    assert err.value.field == "observations.front_points"


def test_oversized_messages_are_rejected_before_parsing():
    data = encode(synthetic_episode())
    with pytest.raises(ProtocolError, match="exceeds the limit"):
        decode(data, max_bytes=len(data) - 1)
    assert isinstance(decode(data, max_bytes=len(data)), Episode)


# -- hostile content: what a buggy actor, a real camera or an attacker sends -----------------

from protocol import DEFAULT_LIMITS, MAX_INT, Limits, validate  # noqa: E402
from protocol.codec import encode_frame  # noqa: E402
from protocol.messages import Kind  # noqa: E402


def labelled_episode(steps: int = 2, depths: int = 3):
    """A small episode with the act-time labels an actor records (extras)."""
    episode = synthetic_episode(steps=steps, size=8)
    n = steps + 1
    episode.observations["extra_voxel_indices"] = np.zeros((n, depths, 3), np.int64)
    episode.observations["extra_attention_coordinates"] = np.zeros((n, depths, 3), np.float32)
    episode.observations["extra_rot_grip_indices"] = np.zeros((n, 4), np.int64)
    return episode


def raw_episode_frame(episode, **field_overrides) -> bytes:
    """An episode frame built without encode()'s checks, as a buggy or foreign sender would."""
    fields = {"actor_id": episode.actor_id, "episode_id": episode.episode_id, "task": episode.task,
              "seed": episode.seed, "is_demo": episode.is_demo, "success": episode.success,
              "timeout": episode.timeout, "info": episode.info} | field_overrides
    arrays = {f"obs/{k}": v for k, v in episode.observations.items()}
    arrays |= {f"step/{k}": getattr(episode, k) for k in ("actions", "rewards", "terminals", "policy_versions")}
    return encode_frame(Kind.EPISODE, fields, arrays)


def rejected_field(data: bytes, **kwargs) -> str:
    with pytest.raises(ProtocolError) as err:
        decode(data, **kwargs)
    return err.value.field


def test_nan_in_point_clouds_is_accepted_because_the_voxeliser_drops_it():
    episode = labelled_episode()
    episode.observations["front_points"][:, :2] = np.nan  # invalid depth, as a RealSense reports it
    episode.observations["front_points"][:, 3] = np.inf
    back = decode(encode(episode), expect=Episode)
    assert np.isnan(back.observations["front_points"]).any()


@pytest.mark.parametrize("name", [
    "gripper_pose", "gripper_open", "finger_positions", "joint_positions", "joint_velocities",
    "front_intrinsics", "front_extrinsics", "extra_attention_coordinates",
])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf], ids=["nan", "inf", "-inf"])
def test_non_finite_observations_are_rejected(name, bad):
    episode = labelled_episode()
    episode.observations[name].reshape(-1)[-1] = bad
    assert rejected_field(raw_episode_frame(episode)) == f"observations.{name}"
    with pytest.raises(ProtocolError):
        encode(episode)  # and a sender cannot send it in the first place


@pytest.mark.parametrize("name", ["actions", "rewards"])
def test_non_finite_actions_and_rewards_are_rejected(name):
    episode = labelled_episode()
    getattr(episode, name).reshape(-1)[0] = np.nan
    assert rejected_field(raw_episode_frame(episode)) == name


def test_act_time_labels_are_checked():
    episode = labelled_episode(depths=3)
    episode.observations["extra_attention_coordinates"] = np.zeros((3, 2, 3), np.float32)  # D=2 vs D=3
    assert rejected_field(raw_episode_frame(episode)) == "observations.extra_attention_coordinates"
    episode = labelled_episode()
    episode.observations["extra_rot_grip_indices"][1, 0] = -1
    assert rejected_field(raw_episode_frame(episode)) == "observations.extra_rot_grip_indices"
    episode = labelled_episode()
    episode.observations["extra_voxel_indices"] = np.zeros((3, 3, 2), np.int64)
    assert rejected_field(raw_episode_frame(episode)) == "observations.extra_voxel_indices"


def test_a_bool_array_holding_other_bytes_is_rejected():
    # torch would turn the byte 2 into 2.0, and 1 - terminal into -1 inside the TD target.
    episode = labelled_episode()
    episode.terminals = np.array([0, 2], np.uint8).view(bool)
    assert rejected_field(raw_episode_frame(episode)) == "terminals"


def test_episode_shapes_must_agree_with_the_step_count():
    episode = labelled_episode(steps=2)
    episode.observations["joint_positions"] = episode.observations["joint_positions"][:2]  # T, not T + 1
    assert rejected_field(raw_episode_frame(episode)) == "observations.joint_positions"
    episode = labelled_episode(steps=2)
    del episode.observations["front_extrinsics"]
    assert rejected_field(raw_episode_frame(episode)) == "observations.front_extrinsics"
    episode = labelled_episode(steps=2)
    episode.observations["back_points"] = episode.observations["front_points"]  # a camera without rgb
    assert rejected_field(raw_episode_frame(episode)) == "observations.back_points"


@pytest.mark.parametrize("actor_id", ["*", "**", "a/b", "$*", "a b", "a?", "a#", "", "x" * 65, "a\n", ".."])
def test_ids_that_could_widen_a_key_are_rejected(actor_id):
    # The replay server acks on acks/<actor_id>: "*" once made it publish on a wildcard.
    assert rejected_field(raw_episode_frame(labelled_episode(), actor_id=actor_id)) == "actor_id"
    ack = encode_frame(Kind.ACK, {"actor_id": actor_id, "episode_id": 1, "status": "stored", "reason": "",
                                  "digest": DIGEST}, {})
    assert rejected_field(ack) == "actor_id"
    with pytest.raises(ProtocolError):
        encode(EpisodeAck(actor_id, 1, AckStatus.STORED, digest=DIGEST))


@pytest.mark.parametrize("value", [-1, MAX_INT + 1, 2**64, True, 1.0, "1", None])
def test_integers_are_bounded_and_never_bools_or_floats(value):
    # An integer of more than 16 digits is refused while the JSON is parsed, before int() runs.
    expected = "frame.fields" if value == 2**64 else "episode_id"
    assert rejected_field(raw_episode_frame(labelled_episode(), episode_id=value)) == expected


def test_unknown_and_missing_fields_are_named():
    assert rejected_field(raw_episode_frame(labelled_episode(), colour="red")) == "colour"
    request = {"request_id": 1, "batch_size": 8}
    assert rejected_field(encode_frame(Kind.SAMPLE_REQUEST, request, {})) == "timeout_ms"
    assert rejected_field(encode_frame(Kind.PRIORITY_UPDATE, {}, {"indices": np.zeros(1, np.int64)})) == "keys"


def test_weights_must_be_finite_floats():
    ok = WeightsUpdate(1, 0, {"w": np.ones(3, np.float32)})
    assert isinstance(decode(encode(ok)), WeightsUpdate)
    for tensor in (np.array([1.0, np.nan], np.float32), np.array([np.inf], np.float16), np.ones(2, np.int64)):
        with pytest.raises(ProtocolError) as err:
            encode(WeightsUpdate(1, 0, {"w": tensor}))
        assert err.value.field == "tensors.w"
        fields = {"version": 1, "learner_step": 0, "config_digest": "", "published_at": 0.0, "env_steps": 0}
        assert rejected_field(encode_frame(Kind.WEIGHTS, fields, {"w": tensor})) == "tensors.w"


def test_priorities_must_be_finite_and_non_negative():
    def update(p, indices=(0, 1)):
        i = np.asarray(indices, np.int64)
        return encode_frame(
            Kind.PRIORITY_UPDATE, {}, {"indices": i, "keys": i, "priorities": np.asarray(p, np.float32)}
        )

    assert rejected_field(update([1.0, np.nan])) == "priorities"
    assert rejected_field(update([1.0, -0.5])) == "priorities"
    assert rejected_field(update([1.0, 1.0], indices=(0, -1))) == "indices"


def test_status_counters_may_be_non_finite_but_its_fields_may_not():
    # A diverged loss is what the dashboard must show (as null); refusing the heartbeat would
    # hide the learner instead. Status.time and the ids are checked like everywhere else.
    status = Status("learner", "learner-0", "run-1", 7, "host", 1.7e9, counters={"loss/td": float("nan")})
    back = decode(encode(status), expect=Status)
    assert np.isnan(back.counters["loss/td"])
    fields = {k: getattr(status, k) for k in Status.__dataclass_fields__} | {"time": float("nan")}
    assert rejected_field(encode_frame(Kind.STATUS, fields, {})) == "time"
    fields["time"], fields["instance"] = 0.0, "learner/0"
    assert rejected_field(encode_frame(Kind.STATUS, fields, {})) == "instance"


def test_receivers_pass_their_own_limits():
    episode = synthetic_episode(steps=12, size=16)
    data = encode(episode)
    assert rejected_field(data, limits=Limits(max_steps=10)) == "actions"
    assert rejected_field(data, limits=Limits(max_image_side=8)) == "observations.front_rgb"
    assert rejected_field(encode(synthetic_episode(cameras=("a", "b", "c"), steps=1, size=4)),
                          limits=Limits(max_cameras=2)) == "observations"

    big = encode(SampleRequest(1, batch_size=DEFAULT_LIMITS.max_batch))
    assert rejected_field(big, limits=Limits(max_batch=256)) == "batch_size"
    with pytest.raises(ProtocolError):
        encode(SampleRequest(1, batch_size=65536))  # ~19 GB of batch at 4 cameras
    huge = SampleRequest(1, batch_size=4096)
    assert decode(encode(huge, limits=Limits(max_batch=4096)), limits=Limits(max_batch=4096)) == huge

    n = 100
    update = PriorityUpdate(np.arange(n), np.arange(n), np.ones(n, np.float32))
    assert rejected_field(encode(update), limits=Limits(max_priorities=n - 1)) == "priorities"


def test_the_json_header_is_bounded_in_size_and_depth():
    import json
    import struct

    from protocol.codec import MAGIC

    def frame(header: bytes) -> bytes:
        return struct.pack("<4sHHQ", MAGIC, 1, Kind.STATUS, len(header)) + header

    deep = json.dumps({"__metadata__": {"fields": "[" * 100_000 + "]" * 100_000}}).encode()
    assert rejected_field(frame(deep)) == "frame.fields"  # never a RecursionError
    assert rejected_field(frame(b"[" * 1000)) == "frame.header"
    padded = json.dumps({"__metadata__": {"fields": "{}"}}).encode() + b" " * (2 << 20)
    assert rejected_field(frame(padded)) == "frame.header"  # 2 MiB header > 1 MiB limit
    duplicate = b'{"__metadata__": {"fields": "{}"}, "__metadata__": {"fields": "{}"}}'
    assert rejected_field(frame(duplicate)) == "frame.header"


def test_array_tables_are_checked_before_any_buffer_is_read():
    import json
    import struct

    from protocol.codec import MAGIC

    def weights(entry: dict, data: bytes = b"\0" * 8) -> bytes:
        fields = {"version": 1, "learner_step": 0, "config_digest": "", "published_at": 0.0, "env_steps": 0}
        header = json.dumps({"__metadata__": {"fields": json.dumps(fields)}, "w": entry}).encode()
        return struct.pack("<4sHHQ", MAGIC, 1, Kind.WEIGHTS, len(header)) + header + data

    assert isinstance(decode(weights({"dtype": "F32", "shape": [2], "data_offsets": [0, 8]})), WeightsUpdate)
    for entry in (
        {"dtype": "BF16", "shape": [4], "data_offsets": [0, 8]},  # safetensors knows it, the wire does not
        {"dtype": "F32", "shape": [2**40, 2**40], "data_offsets": [0, 8]},
        {"dtype": "F32", "shape": [3], "data_offsets": [0, 8]},
        {"dtype": "F32", "shape": [2], "data_offsets": [0, 16]},
        {"dtype": "F32", "shape": [-2], "data_offsets": [0, 8]},
        {"dtype": "F32", "shape": [2], "data_offsets": [0, 8], "extra": 1},
    ):
        assert rejected_field(weights(entry)) in ("w", "frame.arrays"), entry


def test_anything_decode_accepts_passes_validate():
    for message in _messages():
        validate(decode(encode(message)))
