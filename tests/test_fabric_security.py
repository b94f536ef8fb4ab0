"""A secure fabric: `c2farm certs`, Zenoh TLS with mutual authentication, and the router's access rules.

Real Zenoh sessions over TLS on loopback; the router is the router role's own code path
(``zenoh_config`` plus ``access_control``). A denied put is dropped silently at the router,
so every "cannot" below is asserted on the receiving side.
"""

from __future__ import annotations

import datetime
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest
from conftest import get_free_port, kill_launcher, small_launch, status_reader, stop_launcher, wait_for

from deploy.access_control import access_control
from deploy.certs import CertsPlan, certificate_names, check_certificate, make_certs
from protocol import keys
from protocol.config_checks import is_loopback_host
from protocol.fabric import FabricConfig, open_session, zenoh_config

RUN = "sec"


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("certs")
    make_certs(CertsPlan(directory, hubs=["10.77.0.1"], actors=2, extra=["robot.robot-0"]))
    return directory


@pytest.fixture
def secure_router(certs: Path):
    """A router with TLS, mTLS and the run's access rules; yields a function that opens a client as a name."""
    endpoint = f"tcp/127.0.0.1:{get_free_port()}"
    fabric = FabricConfig(listen=[endpoint], connect=[endpoint], certs=str(certs), identity="router.router")
    zconfig = zenoh_config(fabric, "router")
    zconfig.insert_json5("access_control", json.dumps(access_control(RUN, certificate_names(certs))))
    router = open_session(fabric, "router", zconfig)
    sessions = []

    def client(name: str, directory: Path = certs):
        session = open_session(FabricConfig(connect=[endpoint], certs=str(directory), identity=name))
        sessions.append(session)
        return session

    client.endpoint = endpoint
    yield client
    for session in sessions:
        session.close()
    router.close()


class Inbox:
    """What one session receives on a key."""

    def __init__(self, session, key: str):
        self.payloads: list[bytes] = []
        self._lock = threading.Lock()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, sample) -> None:
        with self._lock:
            self.payloads.append(bytes(sample.payload.to_bytes()))


def test_certs_makes_one_private_key_per_process_and_keeps_what_exists(tmp_path: Path):
    made = make_certs(CertsPlan(tmp_path, actors=1))
    assert (tmp_path / "ca.pem").is_file() and (tmp_path / "curve" / "clients" / "learner.key").is_file()
    for key in [*tmp_path.glob("zenoh/*.key"), tmp_path / "ca.key", *tmp_path.glob("curve/*.key_secret")]:
        assert key.stat().st_mode & 0o777 == 0o600, key
    assert sorted(certificate_names(tmp_path)) == sorted(CertsPlan(tmp_path, actors=1).identities())
    ca = (tmp_path / "ca.pem").read_bytes()
    again = make_certs(CertsPlan(tmp_path, actors=3))  # one more actor host: only what is missing
    assert (tmp_path / "ca.pem").read_bytes() == ca
    assert sorted(p.name for p in again) == ["actor.actor-1.key", "actor.actor-1.pem",
                                             "actor.actor-2.key", "actor.actor-2.pem"]
    assert len(made) > len(again)


def test_a_bad_certificate_is_refused_in_one_line_before_anything_opens(tmp_path: Path, certs: Path):
    check_certificate(certs, "actor.actor-0")  # a good one passes
    with pytest.raises(ValueError, match="missing"):
        check_certificate(certs, "actor.actor-9")
    other = tmp_path / "other"
    make_certs(CertsPlan(other, actors=1))
    (tmp_path / "mixed" / "zenoh").mkdir(parents=True)
    (tmp_path / "mixed" / "ca.pem").write_bytes((certs / "ca.pem").read_bytes())
    for suffix in ("pem", "key"):
        data = (other / "zenoh" / f"actor.actor-0.{suffix}").read_bytes()
        target = tmp_path / "mixed" / "zenoh" / f"actor.actor-0.{suffix}"
        target.write_bytes(data)
        target.chmod(0o600)
    with pytest.raises(ValueError, match="not signed by"):
        check_certificate(tmp_path / "mixed", "actor.actor-0")
    later = datetime.datetime.now(datetime.timezone.utc) + datetime.timedelta(days=400)
    with pytest.raises(ValueError, match="expired"):
        check_certificate(certs, "actor.actor-0", now=later)
    (tmp_path / "mixed" / "zenoh" / "actor.actor-0.key").chmod(0o644)
    with pytest.raises(ValueError, match="readable by others"):
        check_certificate(tmp_path / "mixed", "actor.actor-0")


def test_plain_tcp_beyond_loopback_needs_certs_or_insecure():
    assert is_loopback_host("127.0.0.1") and is_loopback_host("[::1]") and is_loopback_host("localhost")
    assert not is_loopback_host("0.0.0.0") and not is_loopback_host("10.0.0.2")
    FabricConfig(connect=["tcp/127.0.0.1:7447"])  # loopback: zero config
    with pytest.raises(ValueError, match="beyond loopback: pass --certs DIR"):
        FabricConfig(listen=["tcp/0.0.0.0:7447"])
    with pytest.raises(ValueError, match="connect tcp/10.0.0.2:7447 is beyond loopback"):
        FabricConfig(connect=["tcp/10.0.0.2:7447"])
    FabricConfig(connect=["tcp/10.0.0.2:7447"], insecure=True)
    secure = FabricConfig(connect=["tcp/10.0.0.2:7447"], certs="certs", identity="actor.actor-0")
    assert secure.endpoints("connect") == ["tls/10.0.0.2:7447"]


def test_the_cli_refuses_an_open_address_without_certs_in_one_line(tmp_path: Path):
    cmd = [sys.executable, "-m", "deploy.cli", "actor", "--run-id", RUN, "--runs-dir", str(tmp_path),
           "--connect", "tcp/10.0.0.2:7447"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "c2farm: config error: fabric.connect tcp/10.0.0.2:7447 is beyond loopback: pass --certs DIR (made by "
        "`c2farm certs`) for TLS, or --insecure to trust every host that reaches it"]
    missing = subprocess.run([*cmd[:-2], "--certs", str(tmp_path / "none")], capture_output=True, text=True,
                             timeout=120)
    assert missing.returncode == 2 and "c2farm: cannot start: fabric.certs:" in missing.stderr
    assert "none/ca.pem: missing (make it with `c2farm certs" in missing.stderr


def test_clients_without_our_authority_or_a_certificate_are_refused(secure_router, tmp_path: Path):
    secure_router("actor.actor-0")  # ours: opens
    stranger = tmp_path / "stranger"
    make_certs(CertsPlan(stranger, actors=1))
    with pytest.raises(ConnectionError, match="cannot open a zenoh client session"):
        secure_router("actor.actor-0", stranger)  # a certificate from another authority
    with pytest.raises(ConnectionError):
        open_session(FabricConfig(connect=[secure_router.endpoint]))  # plain TCP to a TLS port


def test_each_name_may_do_only_what_its_role_does(secure_router):
    replay, learner = secure_router("replay.replay"), secure_router("learner.learner")
    actor0, actor1 = secure_router("actor.actor-0"), secure_router("actor.actor-1")
    dashboard = secure_router("dashboard.dashboard")
    episodes = Inbox(replay, keys.episodes(RUN, "*"))
    weights_at_actor1 = Inbox(actor1, keys.weights(RUN))
    acks_at_actor1 = Inbox(actor1, keys.acks(RUN, "actor-1"))
    acks_at_actor0 = Inbox(actor0, keys.acks(RUN, "*"))  # subscribing to every actor's acks
    statuses = Inbox(dashboard, keys.status(RUN))
    weights_at_dashboard = Inbox(dashboard, keys.weights(RUN))
    time.sleep(0.5)  # declarations reach the router

    def put(session, key: str, payload: bytes) -> None:  # as the roles do: through a declared publisher
        publisher = session.declare_publisher(key)
        time.sleep(0.3)  # it learns of the subscribers (write-side filtering)
        publisher.put(payload)

    put(actor0, keys.episodes(RUN, "actor-0"), b"mine")
    put(actor0, keys.episodes(RUN, "actor-1"), b"forged episode")  # another actor's key
    put(actor0, keys.weights(RUN), b"forged weights")  # only the learner publishes weights
    put(actor0, keys.status(RUN, "learner", "learner"), b"forged status")  # another role's status
    put(actor0, keys.status(RUN, "actor", "actor-0"), b"own status")
    put(learner, keys.weights(RUN), b"weights")
    replay.put(keys.acks(RUN, "actor-1"), b"ack")
    wait_for(lambda: b"ack" in acks_at_actor1.payloads and b"weights" in weights_at_actor1.payloads
             and b"own status" in statuses.payloads, 10, "the allowed messages")
    time.sleep(0.5)  # a denied message would have arrived by now
    assert episodes.payloads == [b"mine"]
    assert weights_at_actor1.payloads == [b"weights"]
    assert statuses.payloads == [b"own status"]
    assert acks_at_actor0.payloads == []  # actor-1's ack does not reach actor-0
    assert weights_at_dashboard.payloads == []  # the dashboard reads status, not weights


def test_a_weights_follower_gets_the_latest_weights_by_query(secure_router):
    """A querier needs ``reply`` on egress, or its get comes back empty."""
    learner, actor = secure_router("learner.learner"), secure_router("actor.actor-0")
    learner.declare_queryable(keys.weights(RUN), lambda query: query.reply(keys.weights(RUN), b"latest"))
    time.sleep(0.3)
    replies = [bytes(r.ok.payload.to_bytes()) for r in actor.get(keys.weights(RUN), timeout=5) if r.ok]
    assert replies == [b"latest"]


def test_a_whole_run_trains_over_tls_with_access_control(tmp_path: Path, certs: Path):
    """Every role of a launch on its own certificate: demos, episodes, acks, weights, evaluations and the
    dashboard's view all pass the router's rules (a missing grant would starve one of them)."""
    launcher, lines, children, dashboard = small_launch("tls", tmp_path, "--certs", str(certs))
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{dashboard}", timeout=5) as http:
            status = status_reader(http, children)
            seen = wait_for(
                lambda: (s := status()) and (s["summary"]["updates"] or 0) >= 6
                and s.get("actor-0", {}).get("counters", {}).get("weights_version", 0) >= 2
                and s.get("actor-0", {}).get("counters", {}).get("acked", 0) > 0
                and s.get("eval", {}).get("counters", {}).get("eval_version", 0) >= 1 and s,
                300, "training, acks, weights at the actor and an evaluation, all over TLS",
            )
            assert any("demo episodes" in line and "(all acknowledged)" in line for line in lines)
            assert all(seen[name]["alive"] for name in ("router", "replay", "learner", "actor-0", "eval"))
        assert any("fabric: TLS with mutual authentication" in line for line in lines)
        assert any("tls/127.0.0.1" in line for line in lines)
        stop_launcher(launcher, children)
    finally:
        kill_launcher(launcher, children)
