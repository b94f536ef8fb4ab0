"""The replay server as a real process: Zenoh ingest from actor processes, ZeroMQ sampling,
SIGKILL + restart, malformed messages, rate limiter. Real sockets on loopback, free ports."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import zenoh
from synthetic_episodes import actor_tag, synthetic_episode

from protocol import keys, transition
from protocol.codec import PROTOCOL_VERSION
from protocol.fabric import FabricConfig, open_session
from protocol.messages import AckStatus, EpisodeAck, Status, decode, encode
from protocol.sample_wire import ReplayClient, ReplayTimeout
from replay_server.checkpoint_files import load_latest

ROOT = Path(__file__).resolve().parents[1]
SIZE = 16  # image side in these tests (the benchmark uses 128)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_process(proc: subprocess.Popen, sig=signal.SIGTERM, timeout=30.0) -> int:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            for child in psutil.Process(proc.pid).children(recursive=True):
                child.kill()
            proc.kill()
            proc.wait(10)
    return proc.returncode


class Fabric:
    """A Zenoh router in the test process, plus a status/ack listener."""

    def __init__(self, run_id: str):
        self.run_id = run_id
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.session = open_session(FabricConfig(listen=[self.endpoint], shared_memory=False), "router")
        self.status: dict[str, Status] = {}
        self.acks: list[EpisodeAck] = []
        self._lock = threading.Lock()
        self._subs = [
            self.session.declare_subscriber(keys.status(run_id, "replay", "*"), self._on_status),
            self.session.declare_subscriber(keys.acks(run_id, "*"), self._on_ack),
        ]

    def _on_status(self, sample) -> None:
        st = decode(sample.payload.to_bytes(), expect=Status)
        with self._lock:
            self.status[st.instance] = st

    def _on_ack(self, sample) -> None:
        ack = decode(sample.payload.to_bytes(), expect=EpisodeAck)
        with self._lock:
            self.acks.append(ack)

    def counters(self, instance="replay") -> dict:
        with self._lock:
            st = self.status.get(instance)
            return dict(st.counters) if st else {}

    def wait_status(self, pred, timeout=30.0, instance="replay", after=0.0) -> dict:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                st = self.status.get(instance)
            if st is not None and st.time > after and st.state == "running" and pred(st.counters):
                return dict(st.counters)
            time.sleep(0.05)
        raise AssertionError(f"status condition not met in {timeout}s; last counters: {self.counters(instance)}")

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.session.close()


class Harness:
    def __init__(self, tmp_path: Path, fabric: Fabric):
        self.tmp, self.fabric = tmp_path, fabric
        self.zmq = f"tcp://127.0.0.1:{free_port()}"
        self.procs: list[subprocess.Popen] = []
        self.server: subprocess.Popen | None = None

    def start_server(self, *settings: str) -> subprocess.Popen:
        cmd = [sys.executable, "-m", "replay_server", "--run-id", self.fabric.run_id, "--run-dir", str(self.tmp),
               "--connect", self.fabric.endpoint, "--zmq-endpoint", self.zmq, "--no-shm",
               "--set", "min_size_to_sample=1", "--set", "status_interval_s=0.2", "--set", "seed=1"]
        for s in settings:
            cmd += ["--set", s]
        log = open(self.tmp / f"server-{len(self.procs)}.log", "w")
        started = time.time()
        self.server = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        self.procs.append(self.server)
        self.fabric.wait_status(lambda c: True, timeout=30, after=started)
        return self.server

    def start_actor(self, actor_id: str, episodes: int, **opts) -> tuple[subprocess.Popen, Path]:
        out = self.tmp / f"{actor_id}-{len(self.procs)}.json"
        cmd = [sys.executable, str(ROOT / "bench" / "fake_actor.py"), "--connect", self.fabric.endpoint,
               "--run-id", self.fabric.run_id, "--actor-id", actor_id, "--episodes", str(episodes),
               "--size", str(SIZE), "--out", str(out)]
        for k, v in opts.items():
            cmd += [f"--{k.replace('_', '-')}", str(v)]
        proc = subprocess.Popen(cmd, cwd=ROOT)
        self.procs.append(proc)
        return proc, out

    def cleanup(self) -> None:
        for p in self.procs:
            stop_process(p, signal.SIGKILL if p is not self.server else signal.SIGTERM, timeout=20)


@pytest.fixture
def fabric(request):
    run_id = "t" + request.node.name.replace("[", "-").replace("]", "")[:40]
    f = Fabric(run_id)
    try:
        yield f
    finally:
        f.close()


@pytest.fixture
def harness(tmp_path, fabric):
    h = Harness(tmp_path, fabric)
    try:
        yield h
    finally:
        h.cleanup()


def episodes_by_tag(actors: dict[str, int]) -> dict:
    return {(actor_tag(a), e): synthetic_episode(a, e, size=SIZE) for a, n in actors.items() for e in range(n)}


def assert_batch_exact(arrays: dict, sources: dict) -> None:
    for i, (tag, eid, t) in enumerate(arrays["extra_tag"]):
        ep = sources[(int(tag), int(eid))]
        for name, arr in ep.observations.items():
            assert arrays[name][i].tobytes() == arr[t].tobytes(), name
            assert arrays[name + "_tp1"][i].tobytes() == arr[t + 1].tobytes(), name
        assert arrays["action"][i].tobytes() == ep.actions[t].tobytes()
        assert arrays["reward"][i] == ep.rewards[t] and arrays["terminal"][i] == ep.terminals[t]
        assert arrays["policy_version"][i] == ep.policy_versions[t]


def test_actors_acked_stored_once_and_sampled_bit_exact(harness, fabric):
    harness.start_server("checkpoint_interval_s=0")
    actors = {"actor-0": 12, "actor-1": 12}
    procs = [harness.start_actor(a, n) for a, n in actors.items()]
    for proc, _ in procs:
        assert proc.wait(90) == 0
    for _, out in procs:
        result = json.loads(out.read_text())
        assert set(result["acks"].values()) == {"stored"} and len(result["acks"]) == 12
    c = fabric.wait_status(lambda c: c["episodes_stored"] == 24)
    assert c["size_transitions"] == 240 and c["rejected"] == 0

    sources = episodes_by_tag(actors)
    with ReplayClient(harness.zmq, batch_size=32, prefetch=3) as client:
        for _ in range(5):
            batch = client.sample(timeout_s=20)
            a = batch.arrays
            for name, (dtype, _) in transition.SAMPLING_FIELDS.items():  # the schema's sampling fields, as named
                assert a[name].dtype == np.dtype(dtype) and a[name].shape == (32,), name
            assert a["weights"].max() == pytest.approx(1.0) and a["is_demo"].dtype == bool
            assert_batch_exact(a, sources)
        # a stale update (wrong keys) is ignored and counted; a valid one is applied
        client.update_priorities(a["indices"], a["keys"] + 10_000, np.ones(32))
        client.update_priorities(a["indices"], a["keys"], np.full(32, 2.0))
        c = fabric.wait_status(lambda c: c["stale_priority_updates"] == 32 and c["priority_updates"] >= 1)

    # the same episodes again: acked DUPLICATE, stored once
    proc, out = harness.start_actor("actor-0", 12)
    assert proc.wait(60) == 0
    assert set(json.loads(out.read_text())["acks"].values()) == {"duplicate"}
    c = fabric.wait_status(lambda c: c["duplicates"] >= 12)
    assert c["episodes_stored"] == 24 and c["size_transitions"] == 240
    assert c["samples_per_insert"] > 0 and c["transitions_sampled"] >= 160
    assert stop_process(harness.server) == 0  # SIGTERM: clean exit with a checkpoint
    path, snap = load_latest(harness.tmp / "replay" / "checkpoints")
    assert sorted((e.actor_id, e.episode_id) for e in snap.episodes) == sorted(
        (a, e) for a, n in actors.items() for e in range(n))


def test_sigkill_mid_stream_loses_nothing_acked(harness, fabric):
    settings = ("checkpoint_interval_s=1", "capacity_transitions=5000")
    harness.start_server(*settings)
    actors = {f"actor-{i}": 40 for i in range(3)}
    procs = [harness.start_actor(a, n, interval=0.03, ack_timeout=1.0, deadline=120) for a, n in actors.items()]
    fabric.wait_status(lambda c: c["episodes_stored"] >= 20 and c["checkpoints"] >= 1, timeout=60)
    time.sleep(0.3)
    harness.server.send_signal(signal.SIGKILL)
    harness.server.wait(10)
    acked_before = {(a.actor_id, a.episode_id) for a in fabric.acks if a.status == AckStatus.STORED}
    assert acked_before and len(acked_before) < 120
    time.sleep(1.0)  # actors keep publishing into the void and will resend
    harness.start_server(*settings)
    for proc, _ in procs:
        assert proc.wait(120) == 0
    results = [json.loads(out.read_text()) for _, out in procs]
    assert all(len(r["acks"]) == 40 for r in results)
    assert sum(r["sends"] for r in results) > 120  # something was resent
    c = fabric.wait_status(lambda c: c["episodes_stored"] == 120, timeout=30)
    assert c["size_transitions"] == 1200
    assert stop_process(harness.server) == 0
    path, snap = load_latest(harness.tmp / "replay" / "checkpoints")
    stored = [(e.actor_id, e.episode_id) for e in snap.episodes]
    assert len(stored) == len(set(stored)) == 120  # nothing lost, nothing duplicated
    assert acked_before <= set(stored)
    sources = {(e.actor_id, e.episode_id): e for e in snap.episodes}
    for key in [("actor-0", 0), ("actor-1", 17), ("actor-2", 39)]:
        src = synthetic_episode(*key, size=SIZE)
        for name, arr in src.observations.items():
            assert sources[key].arrays[name].tobytes() == arr.tobytes()



def test_a_large_store_stops_without_a_checkpoint_and_comes_back_from_its_log(harness, fabric):
    """A multi-GB checkpoint on stop would outlast the launcher's grace; the WAL holds it all."""
    settings = ("checkpoint_interval_s=0", "stop_checkpoint_max_bytes=1")
    harness.start_server(*settings)
    proc, _ = harness.start_actor("actor-0", 10)
    assert proc.wait(60) == 0
    fabric.wait_status(lambda c: c["episodes_stored"] == 10, timeout=30)
    assert stop_process(harness.server) == 0
    assert not list((harness.tmp / "replay" / "checkpoints").glob("*/manifest.json"))  # none written on stop
    started = time.time()
    harness.start_server(*settings)
    c = fabric.wait_status(lambda c: c["size_episodes"] == 10, timeout=30, after=started)
    assert c["wal_replayed_episodes"] == 10


def test_malformed_messages_are_rejected_and_counted(harness, fabric):
    harness.start_server("max_episode_bytes=60000")
    key = keys.episodes(fabric.run_id, "bad-actor")
    good = encode(synthetic_episode("bad-actor", 0, size=SIZE))
    wrong_version = good[:4] + (PROTOCOL_VERSION + 1).to_bytes(2, "little") + good[6:]
    big = encode(synthetic_episode("bad-actor", 1, size=64))  # > 60 000 bytes
    bad_shape = encode(synthetic_episode("bad-actor", 2, size=SIZE + 1))
    ep3 = synthetic_episode("bad-actor", 3, size=SIZE)
    ep3.observations["step"] = ep3.observations["step"].astype(np.float32)  # breaks the schema
    from protocol.codec import encode_frame  # bypass encode()'s validation, as a buggy sender would
    from protocol.messages import Kind
    invalid = encode_frame(Kind.EPISODE, {"actor_id": "bad-actor", "episode_id": 3, "task": "x", "seed": 0,
                                          "is_demo": False, "success": False, "timeout": False, "info": {}},
                           {f"obs/{k}": v for k, v in ep3.observations.items()} | {
                               "step/actions": ep3.actions, "step/rewards": ep3.rewards,
                               "step/terminals": ep3.terminals, "step/policy_versions": ep3.policy_versions})
    status_msg = encode(Status("x", "y", fabric.run_id, 1, "h", 0.0))
    session = fabric.session
    block = zenoh.CongestionControl.BLOCK  # as actors put: the default (DROP) may lose puts on a busy machine
    session.put(key, good, congestion_control=block)  # first valid episode fixes the schema
    fabric.wait_status(lambda c: c["episodes_stored"] == 1)
    for payload in (b"garbage" * 10, good[: len(good) // 2], wrong_version, big, bad_shape, invalid,
                    status_msg, b"", os.urandom(5000)):
        session.put(key, payload, congestion_control=block)
    c = fabric.wait_status(lambda c: c["rejected"] == 9)
    session.put(key, encode(synthetic_episode("bad-actor", 4, size=SIZE)), congestion_control=block)
    c = fabric.wait_status(lambda c: c["episodes_stored"] == 2)
    assert c["rejected"] == 9 and harness.server.poll() is None
    time.sleep(0.3)
    acks = {}
    for a in fabric.acks:  # first ack per episode (the truncated copy of episode 0 is rejected later)
        if a.actor_id == "bad-actor":
            acks.setdefault(a.episode_id, a)
    assert acks[0].status == acks[4].status == AckStatus.STORED
    for eid in (1, 2, 3):  # identity readable: rejected with a reason, so the actor stops resending
        assert acks[eid].status == AckStatus.REJECTED and acks[eid].reason
    assert "max_episode_bytes" in acks[1].reason and "do not match" in acks[2].reason
    assert "step" in acks[3].reason


def test_rate_limiter_times_out_cleanly_and_holds_the_ratio(harness, fabric):
    harness.start_server("min_size_to_sample=30", "samples_per_insert=2", "samples_per_insert_error_buffer=16",
                         "sample_wait_timeout_s=0.5", "checkpoint_interval_s=0")
    with ReplayClient(harness.zmq, batch_size=8, prefetch=2, request_timeout_s=0.5) as client:
        with pytest.raises(ReplayTimeout, match="min_size_to_sample=30"):
            client.sample(timeout_s=1.5)  # no data: the server answers with a reason, no hang
        with pytest.raises(ReplayTimeout, match="no answer"):
            with ReplayClient(f"tcp://127.0.0.1:{free_port()}", 8, request_timeout_s=0.2) as nobody:
                nobody.sample(timeout_s=0.5)
        stop = threading.Event()
        threading.Timer(0.3, stop.set).start()
        with pytest.raises(ReplayTimeout, match="stopped"):  # a stopping learner does not wait out the timeout
            client.sample(timeout_s=600, stop=stop)
        proc, _ = harness.start_actor("actor-0", 5)
        assert proc.wait(60) == 0
        fabric.wait_status(lambda c: c["size_transitions"] == 50)
        sampled = 0
        while True:
            try:
                client.sample(timeout_s=1.5)
                sampled += 8
            except ReplayTimeout as exc:
                assert "samples-per-insert" in str(exc)
                break
        # Reverb semantics: samples <= spi * (inserts - min_size) + buffer = 2 * 20 + 16
        assert 56 - 8 < sampled <= 56
        c = fabric.wait_status(lambda c: c["sample_timeouts"] >= 2)
        assert c["transitions_sampled"] == sampled


def test_served_batches_carry_the_demo_share(harness, fabric):
    harness.start_server("demo_fraction=0.25", "checkpoint_interval_s=0")
    key = keys.episodes(fabric.run_id, "source")
    block = zenoh.CongestionControl.BLOCK  # as actors put: the default (DROP) may lose puts on a busy machine
    fabric.session.put(key, encode(synthetic_episode("source", 0, size=SIZE, is_demo=True)), congestion_control=block)
    for eid in range(1, 8):
        fabric.session.put(key, encode(synthetic_episode("source", eid, size=SIZE)), congestion_control=block)
    c = fabric.wait_status(lambda c: c["episodes_stored"] == 8)
    assert (c["demo_transitions"], c["agent_transitions"]) == (10, 70)
    with ReplayClient(harness.zmq, batch_size=8, prefetch=1) as client:
        for _ in range(3):
            batch = client.sample(timeout_s=20)
            assert batch.arrays["is_demo"].sum() == 2 and batch.info["demo_share"] == 0.25
    c = fabric.wait_status(lambda c: c["demo_transitions_sampled"] >= 6)
    assert c["demo_transitions_sampled"] == c["transitions_sampled"] / 4
