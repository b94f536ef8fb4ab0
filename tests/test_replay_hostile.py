"""The replay server under hostile or buggy senders: real Zenoh sessions and ZeroMQ sockets on
loopback, the service in-process (cheap). Every refusal is counted by reason, nothing good
is lost because of something bad next to it, and the server keeps serving."""
from __future__ import annotations

import contextlib
import os
import socket
import threading
import time

import numpy as np
import pytest
import zenoh
import zmq
from conftest import get_free_port, wait_for
from synthetic_episodes import synthetic_episode

from protocol import keys
from protocol.codec import encode_frame
from protocol.fabric import FabricConfig, open_session
from protocol.messages import EpisodeAck, Kind, decode, encode, encode_unchecked
from protocol.role import RoleContext
from protocol.sample_wire import ReplayClient, ReplayError, parse_batch
from replay_server.config import ReplayConfig
from replay_server.fair_queue import FairQueue
from replay_server.rejections import protocol_reason
from replay_server.service import ReplayService

SIZE = 8


class Replay:
    """A router session (the test's), a replay service on its own client session, an ack listener."""

    def __init__(self, tmp_path, run_id: str, **settings):
        self.run_id = run_id
        self.endpoint = f"tcp/127.0.0.1:{get_free_port()}"
        self.router = open_session(FabricConfig(listen=[self.endpoint], shared_memory=False), "router")
        self.acks: list[tuple[str, EpisodeAck]] = []
        self._lock = threading.Lock()
        self._sub = self.router.declare_subscriber(f"c2farm/{run_id}/acks/**", self._on_ack)
        config = ReplayConfig(**({"zmq_endpoint": f"tcp://127.0.0.1:{get_free_port()}", "min_size_to_sample": 1,
                                  "checkpoint_interval_s": 0, "checkpoint_on_stop": False, "wal_fsync": False,
                                  "checkpoint_dir": str(tmp_path / "replay"), "status_interval_s": 0.5,
                                  "seed": 1} | settings))
        self.session = self.client_session()
        ctx = RoleContext(run_id=run_id, instance="replay", run_dir=tmp_path)
        self.service = ReplayService(config, ctx, self.session)
        self.service.start()
        self.zmq = self.service.zmq_endpoint
        probe = self.router.declare_publisher(keys.episodes(run_id, "probe"))
        wait_for(lambda: probe.matching_status, 30, "the replay's subscription to reach the router")
        probe.undeclare()

    def client_session(self) -> zenoh.Session:
        return open_session(FabricConfig(connect=[self.endpoint], shared_memory=False))

    def _on_ack(self, sample) -> None:
        with self._lock:
            self.acks.append((str(sample.key_expr), decode(sample.payload.to_bytes(), expect=EpisodeAck)))

    def acks_of(self, actor: str) -> dict[int, list[str]]:
        with self._lock:
            out: dict[int, list[str]] = {}
            for key, ack in self.acks:
                if ack.actor_id == actor:
                    out.setdefault(ack.episode_id, []).append(ack.status.value)
            return out

    def c(self) -> dict[str, float]:
        return self.service.counters()

    def wait(self, pred, timeout=20.0):
        try:
            return wait_for(lambda: pred(c := self.c()) and c, timeout, "replay counters")
        except AssertionError:
            interesting = {k: v for k, v in self.c().items() if v and not k.startswith(("capacity", "last_"))}
            raise AssertionError(f"counter condition not met in {timeout}s: {interesting}") from None

    def put(self, actor: str, payload: bytes, session=None) -> None:
        (session or self.router).put(keys.episodes(self.run_id, actor), payload,
                                     congestion_control=zenoh.CongestionControl.BLOCK)  # as actors put

    def close(self) -> None:
        self.service.close()
        self.session.close()
        self._sub.undeclare()
        self.router.close()


@contextlib.contextmanager
def paused_ingest(r: Replay):
    """Hold the ingest thread before it takes its next group (Zenoh callbacks keep queueing)."""
    queue, gate = r.service.queue, threading.Event()
    take = queue.get_batch

    def gated(max_items, timeout):
        gate.wait(60)
        return take(max_items, timeout)

    queue.get_batch = gated
    time.sleep(0.5)  # longer than one idle get_batch wait: the thread is now at the gate
    try:
        yield
    finally:
        gate.set()
        queue.get_batch = take


@pytest.fixture
def make_replay(tmp_path, request):
    made = []

    def make(**settings) -> Replay:
        r = Replay(tmp_path, "h" + request.node.name[5:30].replace("_", "-"), **settings)
        made.append(r)
        return r

    yield make
    for r in made:
        r.close()


def test_fair_queue_round_robin_and_quotas():
    q = FairQueue(max_items=5, max_bytes=1000, sender_items=3, sender_bytes=1000)
    assert [q.put("flood", i, 10, timeout=0) for i in range(5)] == ["", "", "", "sender_quota", "sender_quota"]
    assert q.put("b", "b0", 10, timeout=0) == "" and q.put("c", "c0", 10, timeout=0) == ""
    assert q.put("d", "d0", 10, timeout=0.05) == "backpressure"  # full across senders: bounded wait
    assert q.get_batch(10, timeout=0) == [0, "b0", "c0", 1, 2]
    assert q.peak_items == 5 and len(q) == 0 and q.senders == 0


def test_protocol_errors_are_named_by_reason():
    from protocol.codec import ProtocolError

    cases = {("frame.magic", "expected b'C2FA'"): "decode", ("frame", "9 bytes exceeds the limit of 8"): "too_large",
             ("observations.gripper_pose", "holds NaN or infinite values"): "nonfinite",
             ("actor_id", "invalid id '*'"): "bad_id", ("observations.step", "dtype float32"): "schema",
             ("obs/x", "bad data offsets [1, 2]"): "decode"}
    for (field, reason), expected in cases.items():
        assert protocol_reason(ProtocolError(field, reason)) == expected, (field, reason)


def test_one_bad_episode_never_takes_its_group_down(make_replay):
    r = make_replay()
    r.put("a0", encode(synthetic_episode("a0", 0, size=SIZE)))
    r.wait(lambda c: c["episodes_stored"] == 1)
    nan = synthetic_episode("a0", 2, size=SIZE)
    nan.observations["gripper_pose"][3, 1] = np.nan
    mismatch = synthetic_episode("other", 4, size=SIZE)
    group = [encode(synthetic_episode("a0", 1, size=SIZE)), encode_unchecked(nan),
             encode(synthetic_episode("a0", 3, size=SIZE)), encode(mismatch), b"C2FA" + os.urandom(300),
             encode(synthetic_episode("a0", 5, size=SIZE))[:-7], encode(synthetic_episode("a0", 6, size=SIZE))]
    with paused_ingest(r):  # the whole group queues, and is then taken as one
        for payload in group:
            r.put("a0", payload)
        wait_for(lambda: len(r.service.queue) == len(group), 20, "the group to queue")
    c = r.wait(lambda c: c["episodes_stored"] == 4 and c["rejected"] == 4)
    assert c["ingest_rejected_nonfinite"] == 1 and c["ingest_rejected_key_mismatch"] == 1
    assert c["ingest_rejected_decode"] == 2 and c["ingest_errors"] == 0
    acks = wait_for(lambda: (a := r.acks_of("a0")) and len(a) >= 6 and a, 20, "acks")
    assert [acks[e] for e in (0, 1, 3, 6)] == [["stored"]] * 4
    assert acks[2] == ["rejected"] and 5 in acks  # named, so told not to resend
    assert "other" not in {a.actor_id for _, a in r.acks}  # a mismatched episode is never acked


def test_too_large_sample_requests_are_refused_with_a_reply(make_replay):
    r = make_replay(max_batch_size=16)
    payloads = [encode(synthetic_episode("a0", eid, size=SIZE)) for eid in range(3)]
    for _ in range(4):  # a put can be lost on a busy machine: resend as an actor would (stored once)
        for payload in payloads:
            r.put("a0", payload)
        try:
            r.wait(lambda c: c["episodes_stored"] == 3, timeout=5.0)
            break
        except AssertionError:
            pass
    r.wait(lambda c: c["episodes_stored"] == 3)
    with ReplayClient(r.zmq, batch_size=17, prefetch=1) as big:
        with pytest.raises(ReplayError, match="max_batch_size=16"):
            big.sample(timeout_s=10)
    with zmq.Context() as ctx, ctx.socket(zmq.DEALER) as dealer:  # beyond even the protocol's ceiling
        dealer.setsockopt(zmq.LINGER, 0)
        dealer.connect(r.zmq)
        dealer.send(encode_frame(Kind.SAMPLE_REQUEST, {"request_id": 9, "batch_size": 10**9, "timeout_ms": 100}, {}))
        assert dealer.poll(10_000)
        reply = parse_batch(dealer.recv_multipart())
        assert reply.request_id == 9 and reply.error.startswith("refused")
    c = r.c()
    assert c["zmq_rejected_batch_too_large"] >= 2 and c["batches_served"] == 0
    with ReplayClient(r.zmq, batch_size=16, prefetch=1) as ok:
        assert ok.sample(timeout_s=10).arrays["indices"].shape == (16,)
    with ReplayClient(r.zmq, batch_size=4, prefetch=1) as ok:  # bytes: 4 items fit, 16 would not
        r.service.config.max_batch_bytes = 10 * r.service.sampler._batch_bytes(1)
        assert ok.sample(timeout_s=10).arrays["indices"].shape == (4,)
        with pytest.raises(ReplayError, match="max_batch_bytes"):
            with ReplayClient(r.zmq, batch_size=16, prefetch=1) as over:
                over.sample(timeout_s=10)
    assert r.c()["zmq_rejected_batch_bytes_too_large"] >= 1  # the client re-requests once before raising


def test_impersonation_does_not_suppress_the_real_actors_episodes(make_replay):
    r = make_replay()
    real, fake = r.client_session(), r.client_session()
    try:
        block = zenoh.CongestionControl.BLOCK
        real_pub = real.declare_publisher(keys.episodes(r.run_id, "a0"), congestion_control=block)
        fake_pub = fake.declare_publisher(keys.episodes(r.run_id, "a0"), congestion_control=block)
        time.sleep(0.3)
        sn = iter(range(1, 1000))

        def send(pub, ep, sourced=True):
            data = encode(ep)
            pub.put(data, **({"source_info": zenoh.SourceInfo(pub.id, next(sn))} if sourced else {}))

        # 1. the real actor, identified by its session, stores first; a forger with another session is refused
        for eid in range(3):
            send(real_pub, synthetic_episode("a0", eid, size=SIZE))
        r.wait(lambda c: c["episodes_stored"] == 3)
        for eid in range(3, 6):  # the next ids, with other content
            send(fake_pub, synthetic_episode("a0", eid, size=SIZE, timeout=True))
        r.wait(lambda c: c["ingest_rejected_impersonation"] == 3)
        time.sleep(0.2)
        assert not any(e in r.acks_of("a0") for e in range(3, 6))  # no ack the real actor could take for its own
        for eid in range(3, 6):
            send(real_pub, synthetic_episode("a0", eid, size=SIZE))
        r.wait(lambda c: c["episodes_stored"] == 6)

        # 2. without source info (nothing to bind): a forgery stored first does not make the real episode a duplicate
        for eid in (10, 11):
            send(fake_pub, synthetic_episode("a0", eid, size=SIZE, timeout=True), sourced=False)
        r.wait(lambda c: c["episodes_stored"] == 8)
        for eid in (10, 11):
            send(real_pub, synthetic_episode("a0", eid, size=SIZE), sourced=False)
        c = r.wait(lambda c: c["episodes_stored"] == 10)
        assert c["ingest_suspect_id_conflict"] == 2
        send(real_pub, synthetic_episode("a0", 10, size=SIZE), sourced=False)  # a true resend is still a duplicate
        c = r.wait(lambda c: c["duplicates"] == 1)
        assert c["episodes_stored"] == 10
        stored = {(e.actor_id, e.episode_id, e.timeout) for e in r.service.store.ring.episodes.values()}
        assert {("a0", e, False) for e in (*range(6), 10, 11)} <= stored
    finally:
        real.close()
        fake.close()



def test_a_restarted_actor_gets_its_id_back_when_the_old_session_is_gone(make_replay):
    """The binding is released by the old session's liveliness token going away, not the TTL."""
    r = make_replay(identity_bind_ttl_s=600.0)
    block = zenoh.CongestionControl.BLOCK
    old = r.client_session()
    token = old.liveliness().declare_token(keys.alive(r.run_id, "actor", "a0"))
    pub = old.declare_publisher(keys.episodes(r.run_id, "a0"), congestion_control=block)
    time.sleep(0.3)
    pub.put(encode(synthetic_episode("a0", 0, size=SIZE)), source_info=zenoh.SourceInfo(pub.id, 1))
    r.wait(lambda c: c["episodes_stored"] == 1)
    token.undeclare()
    old.close()  # the actor process died
    r.wait(lambda c: c["identity_released"] == 1)
    new = r.client_session()
    try:
        pub = new.declare_publisher(keys.episodes(r.run_id, "a0"), congestion_control=block)
        time.sleep(0.3)
        pub.put(encode(synthetic_episode("a0", 1, size=SIZE)), source_info=zenoh.SourceInfo(pub.id, 1))
        c = r.wait(lambda c: c["episodes_stored"] == 2)
        assert c["ingest_rejected_impersonation"] == 0
    finally:
        new.close()


def test_wildcard_or_garbage_ids_never_get_an_ack(make_replay):
    r = make_replay()
    good = encode(synthetic_episode("a0", 0, size=SIZE))
    prefix = keys.episodes(r.run_id, "*")[:-1]
    for segment in ("*", "**", "a$*", "a b", "..", "-x"):
        r.router.put(prefix + segment, good, congestion_control=zenoh.CongestionControl.BLOCK)
    for actor in ("*", "a0/x", "a$*"):  # a valid key, a payload claiming a wildcard id
        ep = synthetic_episode("a0", 1, size=SIZE)
        ep.actor_id = actor
        r.put("a0", encode_unchecked(ep))
    c = r.wait(lambda c: c["ingest_rejected_bad_id"] == 9)
    assert c["episodes_stored"] == 0
    r.put("a0", good)
    r.wait(lambda c: c["episodes_stored"] == 1)
    time.sleep(0.2)
    with r._lock:
        ack_keys = [k for k, _ in r.acks]
    assert ack_keys == [keys.acks(r.run_id, "a0")]
    assert not any(ch in k for k in ack_keys for ch in "*$ ")


def test_a_flooding_sender_does_not_starve_another(make_replay):
    r = make_replay(ingest_queue_size=8, ingest_sender_queue_size=2)
    flood = [encode(synthetic_episode("flood", eid, size=SIZE)) for eid in range(60)]
    honest = {eid: encode(synthetic_episode("honest", eid, size=SIZE)) for eid in range(5)}
    flooder = r.client_session()
    try:
        with paused_ingest(r):  # the flood arrives faster than it can be stored
            for data in flood:
                r.put("flood", data, session=flooder)
            wait_for(lambda: r.c()["ingest_dropped_sender_quota"] >= 40, 20, "the flood to be throttled")
            for data in honest.values():
                r.put("honest", data)
            wait_for(lambda: r.service.queue.senders == 2, 20, "the honest sender to be queued")
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # the honest actor resends what was not acked, as actors do
            missing = [e for e in honest if "stored" not in r.acks_of("honest").get(e, [])]
            if not missing:
                break
            for e in missing:
                r.put("honest", honest[e])
            time.sleep(0.5)
        assert not missing
        c = r.c()
        assert c["ingest_queue_peak"] <= 8 and c["ingest_queue_peak_bytes"] <= r.service.config.ingest_queue_bytes
        assert 2 <= sum("stored" in v for v in r.acks_of("flood").values()) < 60
        assert c["ingest_dropped_backpressure"] == 0
    finally:
        flooder.close()


def test_random_bytes_are_counted_and_the_server_keeps_serving(make_replay):
    r = make_replay()
    for payload in (os.urandom(2000), b"", b"C2FA\x01\x00\x01\x00" + (10).to_bytes(8, "little") + b"not json!!"):
        r.put("a0", payload)
    r.wait(lambda c: c["ingest_rejected_decode"] == 3)
    with zmq.Context() as ctx:
        dealer = ctx.socket(zmq.DEALER)
        dealer.connect(r.zmq)
        dealer.send(os.urandom(1000))
        dealer.send_multipart([b"a", b"b"])  # [identity, a, b] at the router: wrong frame count
        dealer.send(b"")
        with socket.create_connection(("127.0.0.1", int(r.zmq.rsplit(":", 1)[1]))) as raw:
            raw.sendall(os.urandom(4096))  # not even ZMTP
        dealer.close(linger=2000)
    # random bytes that are not even ZMTP are read by libzmq as legacy ZMTP 1.0 frames: counted as well
    c = r.wait(lambda c: c["zmq_rejected_decode"] >= 2 and c["zmq_rejected_frames"] >= 1)
    assert c["sample_errors"] == 0 and c["callback_errors"] == 0 and c["ingest_errors"] == 0
    r.put("a0", encode(synthetic_episode("a0", 0, size=SIZE)))
    r.wait(lambda c: c["episodes_stored"] == 1)
    with ReplayClient(r.zmq, batch_size=4, prefetch=1) as client:
        assert client.sample(timeout_s=10).arrays["indices"].shape == (4,)


def test_bad_priority_updates_are_rejected_counted_and_never_applied(make_replay):
    r = make_replay()
    r.put("a0", encode(synthetic_episode("a0", 0, size=SIZE)))
    r.wait(lambda c: c["episodes_stored"] == 1)
    with ReplayClient(r.zmq, batch_size=4, prefetch=1) as client:
        a = client.sample(timeout_s=10).arrays
    before = r.service.store.priorities.tree.leaves().copy()
    idx, k = np.array(a["indices"]), np.array(a["keys"])

    def update(indices, item_keys, priorities) -> bytes:
        return encode_frame(Kind.PRIORITY_UPDATE, {}, {"indices": indices, "keys": item_keys, "priorities": priorities})

    with zmq.Context() as ctx:
        dealer = ctx.socket(zmq.DEALER)
        dealer.connect(r.zmq)
        dealer.send(update(idx, k, np.array([1.0, np.nan, 1.0, 1.0], np.float32)))
        dealer.send(update(idx, k, np.array([1.0, np.inf, 1.0, 1.0], np.float32)))
        dealer.send(update(idx, k, np.array([1.0, -1.0, 1.0, 1.0], np.float32)))
        dealer.send(update(idx, k[:3], np.ones(4, np.float32)))  # wrong length
        dealer.send(update(idx + 10**9, k, np.ones(4, np.float32)))  # out of range
        dealer.close(linger=2000)
    c = r.wait(lambda c: c["priority_updates_rejected"] == 5)
    assert c["zmq_rejected_priorities_nonfinite"] >= 2 and c["zmq_rejected_priorities_range"] == 1
    assert c["zmq_rejected_priorities_length"] == 1
    assert c["priority_updates"] == 0 and np.array_equal(r.service.store.priorities.tree.leaves(), before)
    with ReplayClient(r.zmq, batch_size=4, prefetch=1) as client:  # a sane one is applied
        client.update_priorities(idx, k, np.full(4, 3.0))
        r.wait(lambda c: c["priority_updates"] == 4)
