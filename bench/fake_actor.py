"""A minimal at-least-once actor for tests and benchmarks (a test double for ``actors/``).

    python bench/fake_actor.py --connect tcp/127.0.0.1:7447 --run-id r --actor-id a0 --out a0.json

It puts synthetic episodes (BLOCK congestion control), keeps a bounded outbox of unacked
ones, resends after a timeout, and writes a JSON summary (``acks`` by episode id, ``sends``).
Exits 0 once every episode was acked. Used by tests/test_replay_service.py and
bench/bench_replay.py; it lives in bench/ so that benchmarks need nothing from tests/.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time

from synthetic_episodes import synthetic_episode  # bench/synthetic_episodes.py


def run_actor(argv: list[str]) -> int:
    """A minimal actor: publish episodes, wait for acks, resend unacked ones."""
    p = argparse.ArgumentParser(prog="bench/fake_actor.py")
    p.add_argument("--connect", required=True)
    p.add_argument("--run-id", required=True)
    p.add_argument("--actor-id", required=True)
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--start-id", type=int, default=0)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--size", type=int, default=16)
    p.add_argument("--cameras", type=int, default=1)
    p.add_argument("--outbox", type=int, default=8, help="most unacked episodes in flight")
    p.add_argument("--ack-timeout", type=float, default=1.0)
    p.add_argument("--interval", type=float, default=0.0, help="seconds between new episodes")
    p.add_argument("--deadline", type=float, default=90.0)
    p.add_argument("--template", action="store_true", help="reuse one episode's arrays (fast; for benchmarks)")
    p.add_argument("--source-info", action="store_true", help="attach Zenoh source info (publisher id) to every put")
    p.add_argument("--certs", default="", help="keys of `c2farm certs`: TLS as actor.<actor-id>")
    p.add_argument("--insecure", action="store_true", help="plain TCP beyond loopback")
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)

    import zenoh

    from protocol import keys
    from protocol.fabric import FabricConfig, open_session
    from protocol.messages import EpisodeAck, decode, encode
    from protocol.observation import CAMERA_NAMES

    session = open_session(FabricConfig(connect=[a.connect], certs=a.certs, insecure=a.insecure,
                                        identity=f"actor.{a.actor_id}"))
    acks: dict[int, str] = {}
    lock = threading.Lock()

    def on_ack(sample) -> None:
        try:
            ack = decode(sample.payload.to_bytes(), expect=EpisodeAck)
        except Exception:
            return
        with lock:
            acks.setdefault(ack.episode_id, ack.status.value)

    sub = session.declare_subscriber(keys.acks(a.run_id, a.actor_id), on_ack)
    pub = session.declare_publisher(
        keys.episodes(a.run_id, a.actor_id), congestion_control=zenoh.CongestionControl.BLOCK
    )
    sequence = iter(range(1, 1 << 62))

    def put(data: bytes) -> None:
        if a.source_info:  # lets the replay bind this actor id to this session (replay_server.identity)
            pub.put(data, source_info=zenoh.SourceInfo(pub.id, next(sequence)))
        else:
            pub.put(data)

    cams = tuple(CAMERA_NAMES[: a.cameras])
    todo = list(range(a.start_id, a.start_id + a.episodes))
    outbox: dict[int, tuple[bytes, float]] = {}
    sends = 0
    template = synthetic_episode(a.actor_id, 0, steps=a.steps, cameras=cams, size=a.size) if a.template else None

    def make(eid: int) -> bytes:
        if template is None:
            return encode(synthetic_episode(a.actor_id, eid, steps=a.steps, cameras=cams, size=a.size))
        template.episode_id = eid
        template.observations["extra_tag"][:, 1] = eid
        return encode(template)

    started = time.monotonic()
    t_end = started + a.deadline
    while time.monotonic() < t_end:
        with lock:
            for eid in [e for e in outbox if e in acks]:
                del outbox[eid]
            done = len(acks) >= a.episodes and all(e in acks for e in range(a.start_id, a.start_id + a.episodes))
        if done:
            break
        now = time.monotonic()
        for eid, (data, sent) in list(outbox.items()):
            if now - sent > a.ack_timeout:
                put(data)
                sends += 1
                outbox[eid] = (data, now)
        while todo and len(outbox) < a.outbox:
            eid = todo.pop(0)
            data = make(eid)
            put(data)
            sends += 1
            outbox[eid] = (data, time.monotonic())
            if a.interval:
                time.sleep(a.interval)
        time.sleep(0.01)
    with lock:
        result = {"acks": {str(k): v for k, v in acks.items()}, "sends": sends,
                  "seconds": time.monotonic() - started, "bytes": len(make(a.start_id))}
    with open(a.out, "w") as f:
        json.dump(result, f)
    sub.undeclare()
    pub.undeclare()
    session.close()
    return 0 if len(result["acks"]) == a.episodes else 1


if __name__ == "__main__":
    sys.exit(run_actor(sys.argv[1:]))
