"""Test and benchmark helpers: synthetic episodes, and a minimal actor process.

``synthetic_episode(actor_id, episode_id, ...)`` is deterministic in its arguments, so a test
can rebuild any episode to compare a sampled batch bit for bit. Every observation carries
``extra_tag`` int64 [3] = (crc32(actor_id), episode_id, t) to find its source.

``python -m replay_server.testing actor ...`` runs a tiny protocol-complete actor: it puts
episodes (BLOCK congestion control), keeps a bounded outbox of unacked ones, resends after a
timeout, and writes a JSON summary. It is a test double for ``actors/``, not a replacement.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time
import zlib

import numpy as np

from protocol.episode import Episode


def actor_tag(actor_id: str) -> int:
    return zlib.crc32(actor_id.encode())


def synthetic_episode(
    actor_id: str = "actor-0",
    episode_id: int = 0,
    steps: int = 10,
    cameras: tuple[str, ...] = ("front",),
    size: int = 128,
    points_dtype=np.float16,
    is_demo: bool = False,
    timeout: bool = False,
    task: str = "reach_target",
    structured: bool = True,
) -> Episode:
    """A valid episode with plausible image statistics (smooth shapes, not white noise, when
    ``structured``), so compression benchmarks are not trivially pessimistic."""
    seed = (actor_tag(actor_id) * 1_000_003 + episode_id) % (2**63)
    rng = np.random.default_rng(seed)
    n = steps + 1
    obs: dict[str, np.ndarray] = {}
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / max(1, size - 1)
    for ci, cam in enumerate(cameras):
        if structured:
            rgb = np.empty((n, size, size, 3), np.uint8)
            pts = np.empty((n, size, size, 3), np.float32)
            for t in range(n):
                base = np.stack([xx, yy, 0.5 * (xx + yy)], -1) * 180 + 30
                cy, cx = rng.uniform(0.2, 0.8, 2)
                blob = ((xx - cx) ** 2 + (yy - cy) ** 2) < 0.02
                base[blob] = rng.uniform(0, 255, 3)
                rgb[t] = (base + rng.integers(0, 4, (size, size, 3))).clip(0, 255)
                depth = 1.0 + 0.3 * yy + 0.1 * blob
                pts[t] = np.stack([xx - 0.5, yy - 0.5, depth], -1) + ci
        else:
            rgb = rng.integers(0, 256, (n, size, size, 3), dtype=np.uint8)
            pts = rng.standard_normal((n, size, size, 3)).astype(np.float32)
        obs[f"{cam}_rgb"] = rgb
        obs[f"{cam}_points"] = pts.astype(points_dtype)
        obs[f"{cam}_intrinsics"] = np.tile(np.eye(3, dtype=np.float32) * (ci + 1), (n, 1, 1))
        obs[f"{cam}_extrinsics"] = rng.standard_normal((n, 4, 4)).astype(np.float32)
    obs["gripper_pose"] = rng.standard_normal((n, 7)).astype(np.float32)
    obs["gripper_open"] = rng.integers(0, 2, n).astype(np.float32)
    obs["finger_positions"] = rng.uniform(0, 0.04, (n, 2)).astype(np.float32)
    obs["joint_positions"] = rng.standard_normal((n, 7)).astype(np.float32)
    obs["joint_velocities"] = rng.standard_normal((n, 7)).astype(np.float32)
    obs["step"] = np.arange(n, dtype=np.int32)
    obs["extra_tag"] = np.stack(
        [np.full(n, actor_tag(actor_id)), np.full(n, episode_id), np.arange(n)], -1
    ).astype(np.int64)
    terminals = np.zeros(steps, bool)
    terminals[-1] = True
    rewards = np.zeros(steps, np.float32)
    rewards[-1] = 0.0 if timeout else 100.0
    return Episode(
        actor_id=actor_id,
        episode_id=episode_id,
        task=task,
        seed=int(seed % (2**31)),
        is_demo=is_demo,
        success=not timeout,
        timeout=timeout,
        observations=obs,
        actions=rng.standard_normal((steps, 8)).astype(np.float32),
        rewards=rewards,
        terminals=terminals,
        policy_versions=np.full(steps, -1 if is_demo else episode_id // 3, np.int64),
        info={"source": "synthetic"},
    )


def run_actor(argv: list[str]) -> int:
    """A minimal actor: publish episodes, wait for acks, resend unacked ones."""
    p = argparse.ArgumentParser(prog="python -m replay_server.testing actor")
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
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)

    import zenoh

    from protocol import keys
    from protocol.fabric import FabricConfig, open_session
    from protocol.messages import EpisodeAck, decode, encode
    from protocol.observation import CAMERA_NAMES

    session = open_session(FabricConfig(connect=[a.connect]))
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

    t_end = time.monotonic() + a.deadline
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
        result = {"acks": {str(k): v for k, v in acks.items()}, "sends": sends}
    with open(a.out, "w") as f:
        json.dump(result, f)
    sub.undeclare()
    pub.undeclare()
    session.close()
    return 0 if len(result["acks"]) == a.episodes else 1


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] != "actor":
        print("usage: python -m replay_server.testing actor --help", file=sys.stderr)
        sys.exit(2)
    sys.exit(run_actor(sys.argv[2:]))
