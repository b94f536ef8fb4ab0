"""A hostile client on a live run: a bounded flood of malformed and hostile-but-parseable
messages on every Zenoh key and on the replay's ZeroMQ endpoint, and what each receiver counted.

    python bench/hostile.py [--rounds 40]     # small `c2farm launch`, flood, table, bench/results/flood.json

Every message is built from a real one captured on the run (an actor's episode, the
learner's weights), then broken or made hostile: random bytes, truncations, bit flips, NaN
rewards and weights, ids too large for the wire, another actor's id (impersonation), a
weights version the learner never announced, forged acks, status under another role's key,
oversized sample requests, NaN priorities. Also imported by tests/test_fault_injection.py,
which floods its live run and asserts that nothing crashed and training carried on.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import random
import signal
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np
import psutil
import zenoh
import zmq

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from protocol import keys  # noqa: E402
from protocol.episode import Episode  # noqa: E402
from protocol.fabric import FabricConfig, open_session  # noqa: E402
from protocol.messages import (  # noqa: E402
    AckStatus,
    EpisodeAck,
    PriorityUpdate,
    SampleRequest,
    Status,
    WeightsUpdate,
    decode,
    encode,
    encode_unchecked,
)

#: (target, kind) of every message the flood sends, one of each per round.
KINDS = [
    ("episodes", "random_bytes"), ("episodes", "truncated"), ("episodes", "bit_flips"),
    ("episodes", "nan_rewards"), ("episodes", "id_too_large"), ("episodes", "other_actors_id"),
    ("acks", "random_bytes"), ("acks", "forged"),
    ("weights", "random_bytes"), ("weights", "unannounced_version"), ("weights", "nan_tensor"),
    ("status", "random_bytes"), ("status", "another_roles_key"),
    ("zmq", "random_bytes"), ("zmq", "many_frames"), ("zmq", "huge_batch"), ("zmq", "nan_priorities"),
]

#: Per target: the receiving instance and the counters (exact names, or families ending in
#: "_") where it records what it refused or set aside.
RECEIVERS = {
    "episodes": ("replay", ("ingest_rejected_", "ingest_dropped_", "ingest_error_")),
    "zmq": ("replay", ("zmq_rejected_", "zmq_error_")),
    "acks": ("actor-0", ("bad_acks", "forged_acks", "unmatched_acks")),
    "weights": ("actor-0", ("weights_rejected_", "weights_superseded")),
    "status": ("dashboard", ("rejected_messages",)),
}


class Captured(NamedTuple):
    """Real messages of the run, to mutate."""

    episode: Episode
    weights: WeightsUpdate


def capture(session: zenoh.Session, run_id: str, timeout_s: float = 300.0) -> Captured:
    """One actor episode (heard on the fabric) and the learner's latest weights (queried)."""
    heard: list[bytes] = []
    sub = session.declare_subscriber(keys.episodes(run_id), lambda s: heard.append(s.payload.to_bytes()))
    deadline = time.monotonic() + timeout_s
    weights = None
    try:
        while time.monotonic() < deadline and (not heard or weights is None):
            if weights is None:
                for reply in session.get(keys.weights(run_id), timeout=2.0):
                    if reply.ok is not None:
                        weights = decode(reply.ok.payload.to_bytes(), expect=WeightsUpdate)
            time.sleep(0.2)
    finally:
        sub.undeclare()
    if not heard or weights is None:
        raise TimeoutError("no episode or no weights on the fabric to mutate")
    return Captured(decode(heard[0], expect=Episode), weights)


def _flip(raw: bytes, rng: random.Random, flips: int = 8) -> bytes:
    data = bytearray(raw)
    for _ in range(flips):  # in the header and JSON, where a flip changes meaning rather than a pixel
        i = rng.randrange(min(len(data), 4096))
        data[i] ^= 1 << rng.randrange(8)
    return bytes(data)


def _episode(cap: Captured, kind: str, n: int, rng: random.Random) -> tuple[str, bytes]:
    """(actor id of the key, payload). Made-up actors ``flood-<n>`` unless impersonating actor-0."""
    ep = cap.episode
    raw = encode(dataclasses.replace(ep, actor_id=f"flood-{n}", episode_id=n))
    if kind == "random_bytes":
        return f"flood-{n}", rng.randbytes(rng.randrange(1, 4096))
    if kind == "truncated":
        return f"flood-{n}", raw[: rng.randrange(1, len(raw))]
    if kind == "bit_flips":  # on another id's key: if the flips still parse, the ids disagree
        return f"flip-{n}", _flip(raw, rng)
    if kind == "nan_rewards":
        rewards = ep.rewards.copy()
        rewards[-1] = np.nan
        return f"flood-{n}", encode_unchecked(dataclasses.replace(ep, actor_id=f"flood-{n}", rewards=rewards))
    if kind == "id_too_large":
        return f"flood-{n}", encode_unchecked(dataclasses.replace(ep, actor_id=f"flood-{n}", episode_id=2**70))
    if kind == "other_actors_id":  # a valid episode claiming actor-0's id, from another session
        return ep.actor_id, encode(dataclasses.replace(ep, episode_id=10**12 + n))
    raise ValueError(kind)


def _weights(cap: Captured, kind: str, rng: random.Random) -> bytes:
    w = cap.weights
    if kind == "random_bytes":
        return rng.randbytes(rng.randrange(1, 4096))
    if kind == "unannounced_version":
        return encode(dataclasses.replace(w, version=2**40))
    if kind == "nan_tensor":
        tensors = dict(w.tensors)
        name = rng.choice(sorted(tensors))
        bad = tensors[name].copy()
        bad.reshape(-1)[0] = np.nan
        return encode_unchecked(dataclasses.replace(w, tensors={**tensors, name: bad}))
    raise ValueError(kind)


def _zmq(kind: str, n: int, rng: random.Random) -> list[bytes]:
    if kind == "random_bytes":
        return [rng.randbytes(rng.randrange(1, 2048))]
    if kind == "many_frames":
        return [rng.randbytes(16) for _ in range(5)]
    if kind == "huge_batch":
        return [encode(SampleRequest(n + 1, 1000, 100))]  # the wire allows 1024; the replay serves at most 512
    if kind == "nan_priorities":
        return [
            encode_unchecked(PriorityUpdate(np.array([0, 1]), np.array([0, 1]), np.array([np.nan, 1.0], np.float32)))
        ]
    raise ValueError(kind)


def flood(session: zenoh.Session, run_id: str, zmq_endpoint: str, cap: Captured, rounds: int,
          seed: int = 0, pause_s: float = 0.01) -> Counter:
    """Send ``rounds`` rounds of every hostile kind; returns messages sent per (target, kind).

    Every put blocks rather than drops when Zenoh's queue is full (as actors put episodes): with
    the default, a busy machine lost some of the flood on the way, and a receiver cannot count
    what never reached it.
    """
    rng = random.Random(seed)
    sent: Counter = Counter()
    block = zenoh.CongestionControl.BLOCK
    imposter = session.declare_publisher(keys.episodes(run_id, cap.episode.actor_id), congestion_control=block)

    def put(key: str, payload: bytes) -> None:
        session.put(key, payload, congestion_control=block)

    ctx = zmq.Context()
    dealer = ctx.socket(zmq.DEALER)
    dealer.setsockopt(zmq.LINGER, 0)
    dealer.connect(zmq_endpoint)
    try:
        for n in range(rounds):
            for target, kind in KINDS:
                if target == "episodes":
                    actor, payload = _episode(cap, kind, n, rng)
                    if kind == "other_actors_id":  # source info names our session, not the actor's
                        imposter.put(payload, source_info=zenoh.SourceInfo(imposter.id, n))
                    else:
                        put(keys.episodes(run_id, actor), payload)
                elif target == "acks":
                    payload = rng.randbytes(rng.randrange(1, 512)) if kind == "random_bytes" else encode(
                        EpisodeAck(cap.episode.actor_id, n, AckStatus.STORED, digest=f"{n:016x}"))
                    put(keys.acks(run_id, cap.episode.actor_id), payload)
                elif target == "weights":
                    put(keys.weights(run_id), _weights(cap, kind, rng))
                elif target == "status":
                    payload = rng.randbytes(rng.randrange(1, 512)) if kind == "random_bytes" else encode(
                        Status("replay", "replay", run_id, os.getpid(), "flood", time.time()))
                    put(keys.status(run_id, "learner", "learner"), payload)
                else:
                    dealer.send_multipart(_zmq(kind, n, rng))
                sent[target, kind] += 1
                time.sleep(pause_s)
        time.sleep(1.0)
        while dealer.poll(200):  # the replay answers refused requests: read them so nothing queues
            dealer.recv_multipart()
    finally:
        imposter.undeclare()
        dealer.close(0)
        ctx.term()
    return sent


def counted(rows: dict, target: str) -> float:
    """What ``target``'s receiver has counted as refused or set aside so far (-1: receiver absent)."""
    instance, names = RECEIVERS[target]
    counters = rows.get(instance, {}).get("counters")
    if counters is None:
        return -1
    return sum(v for k, v in counters.items()
               if any(k.startswith(n) if n.endswith("_") else k == n for n in names))


def accounting(before: dict, after: dict, sent: Counter) -> list[dict]:
    """Per target: sent, counted by its receiver (after - before), and what else the receiver did."""
    out = []
    for target in RECEIVERS:
        n = sum(v for (t, _), v in sent.items() if t == target)
        out.append({"target": target, "receiver": RECEIVERS[target][0], "sent": n,
                    "counted": counted(after, target) - counted(before, target)})
    return out


def main() -> None:
    from bench_reliability import Run  # noqa: PLC0415 (a sibling script, found when run as a script)

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=40, help="rounds of every hostile kind")
    parser.add_argument("--out", default=str(REPO / "bench" / "results" / "flood.json"))
    args = parser.parse_args()
    roles = ["router", "replay", "dashboard", "learner", "actor-0"]
    with tempfile.TemporaryDirectory() as tmp:
        run = Run(Path(tmp), roles, grace_s=60.0)
        try:
            rows = run.wait(lambda: (r := run.rows()) and all(r.get(n, {}).get("alive") for n in roles)
                            and r["learner"]["counters"].get("updates", 0) >= 2 and r, 600)
            assert rows, "the run did not start"
            endpoint = f"tcp/127.0.0.1:{run.ports[0]}"
            session = open_session(FabricConfig(connect=[endpoint], listen=[endpoint]))
            cap = capture(session, "reliability")
            time.sleep(2.0)
            before = run.rows()
            replay = psutil.Process(before["replay"]["pid"])
            rss_before = replay.memory_info().rss
            pids = {n: before[n]["pid"] for n in roles}
            t0 = time.monotonic()
            sent = flood(session, "reliability", f"tcp://127.0.0.1:{run.ports[2]}", cap, args.rounds)
            seconds = time.monotonic() - t0
            time.sleep(5.0)  # heartbeats carry the counts
            after = run.rows()
            rss_after = replay.memory_info().rss
            session.close()
            result = {
                "rounds": args.rounds, "flood_seconds": round(seconds, 1), "messages": sum(sent.values()),
                "accounting": accounting(before, after, sent),
                "same_pids": {n: after.get(n, {}).get("pid") == pids[n] for n in roles},
                "learner_updates": [before["learner"]["counters"]["updates"], after["learner"]["counters"]["updates"]],
                "learner_skipped_or_rejected": {k: after["learner"]["counters"].get(k, 0)
                                                for k in ("skipped_updates", "rejected_batches", "weights_refused")},
                "replay_rss_mb": [round(rss_before / 2**20), round(rss_after / 2**20)],
                "replay_impersonation_rejected": after["replay"]["counters"].get("ingest_rejected_impersonation", 0),
            }
        finally:
            if run.proc.poll() is None:
                run.stop()
            if run.proc.poll() is None:
                os.killpg(run.proc.pid, signal.SIGKILL)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    print("| key / endpoint | receiver | hostile messages sent | counted as refused or set aside |")
    print("|---|---|---|---|")
    for row in result["accounting"]:
        print(f"| {row['target']} | {row['receiver']} | {row['sent']} | {row['counted']:.0f} |")


if __name__ == "__main__":
    main()
