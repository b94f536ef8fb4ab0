"""The dashboard: a registry of roles fed by Zenoh, served over HTTP by a real uvicorn."""

from __future__ import annotations

import threading

import httpx
import pytest
import uvicorn
from conftest import get_free_port, wait_for

from dashboard.app import create_app
from dashboard.metrics import prometheus_text
from dashboard.registry import FabricFeed, RoleTable
from protocol import Status, keys
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def status(role="actor", instance="actor-0", pid=11, counters=None, state="running") -> Status:
    return Status(role, instance, "run-1", pid, "host-a", 0.0, state, counters or {"episodes": 4.0})


def test_the_table_tracks_alive_gone_and_stale():
    clock = FakeClock()
    table = RoleTable("run-1", gone_after_s=3.0, clock=clock)
    table.on_token("actor", "actor-0", True)
    table.on_status(status())
    table.on_token("learner", "learner", True)
    by_name = {r["instance"]: r for r in table.snapshot()["roles"]}
    assert by_name["actor-0"]["alive"] and by_name["actor-0"]["counters"] == {"episodes": 4.0}
    assert by_name["learner"]["alive"]  # a fresh token counts before the first status arrives

    table.on_token("actor", "actor-0", False)  # e.g. the process was SIGKILLed
    snap = table.snapshot()
    actor = next(r for r in snap["roles"] if r["instance"] == "actor-0")
    assert not actor["alive"] and actor["state"] == "gone" and actor["losses"] == 1
    assert actor["counters"] == {"episodes": 4.0}  # last known counters stay visible
    assert (snap["alive"], snap["gone"]) == (1, 1)

    clock.now += 3.5  # the learner's token is still there but it has been silent: stale
    learner = next(r for r in table.snapshot()["roles"] if r["instance"] == "learner")
    assert not learner["alive"] and learner["last_seen_age_s"] == pytest.approx(3.5)

    table.on_token("actor", "actor-0", True)  # restarted under the same name
    table.on_status(status(pid=12))
    actor = next(r for r in table.snapshot()["roles"] if r["instance"] == "actor-0")
    assert actor["alive"] and actor["pid"] == 12 and actor["starts"] == 2


def test_prometheus_text_names_every_instance():
    table = RoleTable("run-1")
    table.on_token("actor", "actor-0", True)
    table.on_status(status(counters={"episodes": 4, "policy lag": 2.5}))
    text = prometheus_text(table.snapshot())
    assert 'c2farm_role_alive{instance="actor-0",role="actor",run="run-1"} 1.0' in text
    assert "# TYPE c2farm_actor_episodes_total counter" in text
    assert 'c2farm_actor_episodes_total{instance="actor-0",role="actor",run="run-1"} 4.0' in text
    # a counter the catalogue does not know is still exported, marked as such
    assert 'c2farm_undocumented{instance="actor-0",name="policy lag",role="actor",run="run-1"} 2.5' in text


@pytest.fixture
def served_table():
    """A RoleTable behind the real FastAPI app on a real uvicorn thread; yields (table, client)."""
    table = RoleTable("run-1", gone_after_s=3.0)
    port = get_free_port()
    server = uvicorn.Server(
        uvicorn.Config(create_app(table, refresh_ms=500), host="127.0.0.1", port=port, log_level="warning",
                       lifespan="off")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: server.started or not thread.is_alive(), 10, "uvicorn to start")
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=5) as client:
            yield table, client
    finally:
        server.should_exit = True
        thread.join(timeout=10)


def test_http_endpoints(served_table):
    table, client = served_table
    table.on_token("replay", "replay", True)
    table.on_status(status("replay", "replay", counters={"size_transitions": 120}))

    body = client.get("/api/status").json()
    assert body["run_id"] == "run-1"
    [replay] = body["roles"]
    assert replay["alive"] and replay["counters"]["size_transitions"] == 120 and replay["pid"] == 11

    assert client.get("/healthz").json() == {"ok": True, "run_id": "run-1", "alive": 1, "gone": 0}
    metrics = client.get("/metrics")
    assert metrics.headers["content-type"].startswith("text/plain")
    assert 'c2farm_replay_stored_transitions{instance="replay",role="replay",run="run-1"} 120.0' in metrics.text
    page = client.get("/")
    assert page.status_code == 200 and "api/status" in page.text and "run-1" in page.text


def test_non_finite_counters_become_null_in_json_and_nan_in_prometheus(served_table):
    table, client = served_table
    nan, inf = float("nan"), float("inf")
    table.on_token("learner", "learner", True)
    table.on_status(status("learner", "learner", counters={"loss/depth0": nan, "weights_version": inf, "updates": 3}))
    table.on_token("actor", "actor-0", True)
    table.on_status(status("actor", "actor-0", counters={"weights_version": 2, "q": -inf}))

    response = client.get("/api/status")
    assert response.status_code == 200
    body = response.json()
    learner = next(r for r in body["roles"] if r["role"] == "learner")
    assert learner["counters"] == {"loss/depth0": None, "weights_version": None, "updates": 3}
    assert body["summary"]["weights_version"] is None and body["summary"]["policy_lag"] == {"actor-0": None}
    assert client.get("/healthz").status_code == 200
    metrics = client.get("/metrics").text
    assert 'c2farm_learner_loss{depth="0",instance="learner",role="learner",run="run-1"} NaN' in metrics
    assert 'c2farm_learner_weights_version{instance="learner",role="learner",run="run-1"} +Inf' in metrics
    assert 'c2farm_undocumented{instance="actor-0",name="q",role="actor",run="run-1"} -Inf' in metrics


def test_the_feed_sees_heartbeats_come_and_go_over_zenoh(router):
    table = RoleTable("run-1", gone_after_s=3.0)
    watcher = open_session(router)
    feed = FabricFeed(watcher, "run-1", table)
    worker = open_session(router)
    try:
        beat = Heartbeat(worker, "run-1", "learner", "learner", counters=lambda: {"steps": 7}, period_s=0.2)

        def learner():
            return next((r for r in table.snapshot()["roles"] if r["instance"] == "learner"), None)

        wait_for(lambda: (r := learner()) and r["alive"] and r["counters"] == {"steps": 7.0}, 10, "learner status")
        beat.close()  # a clean stop withdraws the token
        wait_for(lambda: not learner()["alive"], 10, "learner to be reported gone")
        assert learner()["reported_state"] == "stopped"

        # Another run's heartbeat on the same router is not ours to show.
        other = Heartbeat(worker, "run-2", "actor", "actor-0", period_s=0.2)
        # A malformed status message is counted and does not stop the feed.
        worker.put(keys.status("run-1", "actor", "actor-9"), b"\x00garbage")
        wait_for(lambda: table.snapshot()["rejected_messages"] == 1, 10, "the malformed status to be rejected")
        other.close()
        assert {r["instance"] for r in table.snapshot()["roles"]} == {"learner"}
    finally:
        feed.close()
        worker.close()
        watcher.close()


def test_the_feed_sees_tokens_declared_before_it_started(router):
    worker = open_session(router)
    beat = Heartbeat(worker, "run-1", "router", "router", period_s=0.2)
    watcher = open_session(router)
    table = RoleTable("run-1")
    feed = FabricFeed(watcher, "run-1", table)
    try:
        wait_for(lambda: table.snapshot()["alive"] == 1, 10, "the existing token to be seen")
    finally:
        feed.close()
        beat.close()
        worker.close()
        watcher.close()
