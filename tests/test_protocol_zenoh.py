"""Two real processes exchange an episode over Zenoh on loopback (through a real router).

The sender re-puts the episode until the receiver's EpisodeAck arrives (the at-least-once
rule of the design), so no test depends on how fast a subscription propagates.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import REPO, assert_same_message, stop_process_tree
from synthetic_episodes import synthetic_episode

from protocol import Episode, decode, encode
from protocol.fabric import FabricConfig

PRELUDE = textwrap.dedent(
    """
    import hashlib, json, sys, time
    sys.path.insert(0, {bench!r})  # a child process: pytest's pythonpath does not reach it
    import zenoh
    from synthetic_episodes import synthetic_episode
    from protocol import AckStatus, Episode, EpisodeAck, decode, encode, keys
    from protocol.codec import payload_digest
    from protocol.fabric import FabricConfig, open_session
    fabric = FabricConfig(connect={connect!r}, shared_memory={shm!r})
    session = open_session(fabric)
    """
)

RECEIVER = """
received = []
sub = session.declare_subscriber(keys.episodes("t", "*"), lambda s: received.append(s.payload.to_bytes()))
while not received:
    time.sleep(0.01)
data = received[0]
episode = decode(data, expect=Episode)
open(sys.argv[1], "wb").write(data)
session.put(keys.acks("t", episode.actor_id), encode(EpisodeAck(episode.actor_id, episode.episode_id, AckStatus.STORED,
digest=payload_digest(data))))
print(json.dumps({"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}), flush=True)
time.sleep(0.5)
session.close()
"""

SENDER = """
data = encode(synthetic_episode("actor-5", 42, cameras=("front", "wrist")))
acks = session.declare_subscriber(keys.acks("t", "actor-5"))
publisher = session.declare_publisher(keys.episodes("t", "actor-5"), congestion_control=zenoh.CongestionControl.BLOCK)
ack = None
while ack is None:
    publisher.put(data)
    deadline = time.monotonic() + 0.5
    while ack is None and time.monotonic() < deadline:
        sample = acks.try_recv()
        if sample is None:
            time.sleep(0.01)
        else:
            ack = decode(sample.payload.to_bytes(), expect=EpisodeAck)
print(json.dumps({"sha256": hashlib.sha256(data).hexdigest(), "ack": ack.status.value, "episode_id": ack.episode_id}),
flush=True)
session.close()
"""


def _spawn(script: str, fabric: FabricConfig, *args: str) -> subprocess.Popen:
    code = PRELUDE.format(bench=str(REPO / "bench"), connect=list(fabric.connect), shm=fabric.shared_memory) + script
    return subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=REPO)


def test_an_episode_crosses_zenoh_between_two_processes_byte_for_byte(router, tmp_path: Path):
    out_file = tmp_path / "received.bin"
    receiver = _spawn(RECEIVER, router, str(out_file))
    sender = _spawn(SENDER, router)
    try:
        sent_out, sent_err = sender.communicate(timeout=60)
        got_out, got_err = receiver.communicate(timeout=30)
    finally:
        stop_process_tree(sender)
        stop_process_tree(receiver)
    assert sender.returncode == 0, sent_err
    assert receiver.returncode == 0, got_err
    sent, got = json.loads(sent_out), json.loads(got_out)

    expected = encode(synthetic_episode("actor-5", 42, cameras=("front", "wrist")))
    assert sent["sha256"] == got["sha256"] == hashlib.sha256(expected).hexdigest()
    assert got["bytes"] == len(expected) > 2 * 1024 * 1024
    assert (sent["ack"], sent["episode_id"]) == ("stored", 42)
    assert_same_message(decode(out_file.read_bytes(), expect=Episode), decode(expected))
