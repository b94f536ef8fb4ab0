"""The live view: a Foxglove WebSocket client (subprotocol foxglove.sdk.v1) sees the episode files'
channels advertised and receives a wrapped simulator's frames and next-best poses as they happen."""

import base64
import json
import struct
import time

import numpy as np
import pytest
from websockets.sync.client import connect

from actors.live_view import LiveView
from protocol.mcap_protobuf import message_class


class Client:
    """Just enough of Foxglove: track advertised channels, subscribe to all, decode protobuf messages."""

    def __init__(self, ws) -> None:
        self.ws, self.channels, self.subscribed, self.received = ws, {}, {}, {}

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
                    subs = [{"id": c["id"], "channelId": c["id"]} for c in new]
                    self.subscribed.update({c["id"]: c for c in new})
                    self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
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
