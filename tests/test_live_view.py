"""The live view: a Foxglove WebSocket client (subprotocol foxglove.sdk.v1) sees the episode files'
channels advertised and receives a wrapped simulator's frames and next-best poses as they happen."""

import base64
import json
import re
import struct
import time

import numpy as np
import pytest
from websockets.sync.client import connect

from actors.live_view import LiveView
from protocol.mcap_protobuf import message_class

UNKNOWN = re.compile(r"Unknown channel ID: (\d+)")


class Client:
    """Just enough of Foxglove: track advertised channels, subscribe to all, decode protobuf messages.

    foxglove-sdk (0.30) can advertise a channel a moment before it takes subscriptions to it: a
    subscription sent at once may come back "Unknown channel ID: N", and is then sent again.
    """

    def __init__(self, ws) -> None:
        self.ws, self.channels, self.subscribed, self.received = ws, {}, {}, {}

    def subscribe(self, ids: list[int]) -> None:
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": i} for i in ids]}))

    def pump(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                raw = self.ws.recv(timeout=left)
            except TimeoutError:
                return
            if isinstance(raw, str):
                msg = json.loads(raw)
                if msg["op"] == "advertise":
                    new = [c for c in msg["channels"] if c["id"] not in self.channels]
                    self.channels.update({c["id"]: c for c in new})
                    self.subscribed.update({c["id"]: c for c in new})
                    self.subscribe([c["id"] for c in new])
                elif msg["op"] == "status" and (refused := UNKNOWN.match(msg["message"])):
                    self.subscribe([int(refused.group(1))])
            elif raw[0] == 1:  # message data: subscription id, log time, payload
                sub, _ = struct.unpack_from("<IQ", raw, 1)
                c = self.subscribed[sub]
                cls = message_class(c["schemaName"], base64.b64decode(c["schema"]))
                self.received.setdefault(c["topic"], []).append(cls.FromString(raw[13:]))


@pytest.fixture(scope="module")
def env():
    from actors.panda_env import PandaEnv
    from actors.sim import SimConfig

    env = PandaEnv(SimConfig(task="reach_target", cameras=("front",), image_size=32))
    yield env
    env.close()


def test_a_client_sees_the_scene_live(env):
    with LiveView(port=0) as live, connect(f"ws://127.0.0.1:{live.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
        client = Client(ws)
        client.pump(0.5)
        wrapped = live.wrap(env)
        obs = wrapped.reset(seed=0)
        for _ in range(50):  # subscribing is asynchronous: show the first frame until it arrives
            client.pump(0.1)
            if "/front/image" in client.received:
                break
            live.show(obs)
        topics = {c["topic"] for c in client.channels.values()}
        assert {"/front/image", "/front/depth", "/front/calibration", "/front/points", "/raw/front/calibration",
                "/raw/proprio", "/policy/next_best_pose", "/tf", "/joint_states"} <= topics
        assert all(c["encoding"] == c["schemaEncoding"] == "protobuf" for c in client.channels.values())
        client.received.clear()
        action = np.concatenate([obs.gripper_pose, [1.0]]).astype(np.float32)
        result = wrapped.step(action)
        client.pump(1.0)
        assert [list(m.values) for m in client.received["/policy/next_best_pose"]] == [action.tolist()]
        assert client.received["/front/image"][-1].data == result.observation.cameras["front"].rgb.tobytes()
        assert wrapped.task_name == env.task_name  # everything else passes through


def test_each_decision_shows_its_attention_per_depth_and_its_next_best_pose(env):
    """What ``rollout(..., on_decision=live.show_decision)`` shows of each decision: per depth the box, the chosen
    voxel and the best voxels; the next-best pose as a frame."""
    from qattention import C2FARM, ObservationBatch, QAttentionConfig
    from qattention.cascade import TOP_VOXELS

    config = QAttentionConfig(voxel_size=8, kernels=4, head_width=16, cameras=("front",), image_crop=0, bf16=False)
    agent = C2FARM(config, seed=0)
    with LiveView(port=0) as live, connect(f"ws://127.0.0.1:{live.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
        client = Client(ws)
        client.pump(0.5)
        obs = env.reset(seed=0)
        act = agent.act(ObservationBatch.from_observations([obs], config.cameras))
        for _ in range(50):  # subscribing is asynchronous: show the decision until it arrives
            live.show_decision(obs, act)
            client.pump(0.1)
            if "/policy/attention" in client.received:
                break
        channel = next(c for c in client.channels.values() if c["topic"] == "/policy/attention")
        assert channel["schemaName"] == "foxglove.SceneUpdate"
        scene = client.received["/policy/attention"][-1]
        assert [e.id for e in scene.entities] == ["depth0", "depth1"]
        for d, entity in enumerate(scene.entities):
            box, chosen, *best = entity.cubes
            lo, hi = act.bounds[0, d, :3], act.bounds[0, d, 3:]
            assert entity.frame_id == "world" and len(best) == TOP_VOXELS
            np.testing.assert_allclose([box.size.x, box.size.y, box.size.z], hi - lo, rtol=1e-5)
            np.testing.assert_allclose([chosen.pose.position.x, chosen.pose.position.y, chosen.pose.position.z],
                                       act.attention_coordinates[0, d], rtol=1e-5)
            np.testing.assert_allclose(chosen.size.x, (hi - lo)[0] / config.voxel_size, rtol=1e-5)
            np.testing.assert_allclose([[c.pose.position.x, c.pose.position.y, c.pose.position.z] for c in best],
                                       act.top_voxels[0, d, :, :3], rtol=1e-5)
            assert {kv.key: kv.value for kv in entity.metadata}["step"] == str(obs.step)
            reds = [c.color.r for c in best]
            assert reds[0] == 1.0 and reds[-1] == 0.0  # coloured by Q within the depth: best red, K-th blue
        poses = [t for m in client.received["/tf"] for t in m.transforms if t.child_frame_id == "next_best_pose"]
        np.testing.assert_allclose([poses[-1].translation.x, poses[-1].translation.y, poses[-1].translation.z],
                                   act.action[0, :3], rtol=1e-5)


def test_a_port_already_taken_means_no_live_view_not_a_dead_role():
    """`c2farm launch --robot --foxglove`: the evaluator and the robot actor both ask for 8765; one goes without."""
    from actors.evaluation import live_view

    with LiveView(port=0) as first, live_view(first.port) as second:
        assert second is None
    with live_view(-1) as off:
        assert off is None
