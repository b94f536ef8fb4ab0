"""The dashboard: a registry of roles fed by Zenoh, served over HTTP by a real uvicorn."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import secrets
import stat
import threading
from pathlib import Path

import httpx
import pytest
import uvicorn
from conftest import get_free_port, wait_for

from dashboard.access import TOKEN_FILE, Access, ensure_token, token_path
from dashboard.app import FABRIC_BANNERS, create_app, fabric_security
from dashboard.config import DashboardConfig
from dashboard.metrics import prometheus_text
from dashboard.registry import FabricFeed, RoleTable
from protocol import Status, keys
from protocol.fabric import FabricConfig, open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext

TOKEN = secrets.token_urlsafe(32)


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


def test_a_cut_link_is_not_counted_as_a_dead_process():
    """A router restart withdraws every token at once; the roles come back as the same processes."""
    table = RoleTable("run-1", gone_after_s=3.0, clock=FakeClock())
    table.on_token("actor", "actor-0", True)
    table.on_status(status(pid=11))
    table.on_token("actor", "actor-0", False)  # the router went away
    assert next(r for r in table.snapshot()["roles"])["losses"] == 1  # for now it looks gone
    table.on_token("actor", "actor-0", True)
    table.on_status(status(pid=11))  # the same process, reconnected
    actor = next(r for r in table.snapshot()["roles"])
    assert (actor["losses"], actor["link_losses"], actor["starts"]) == (0, 1, 1)


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


@contextlib.contextmanager
def serving(table: RoleTable, host: str = "127.0.0.1", **options):
    """The real app for ``table`` (token :data:`TOKEN`) on a real uvicorn bound to ``host``; yields a client
    reaching it at 127.0.0.1, sending no token."""
    port = get_free_port()
    server = uvicorn.Server(
        uvicorn.Config(create_app(table, refresh_ms=500, token=TOKEN, host=host, **options), host=host, port=port,
                       log_level="warning", lifespan="off")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: server.started or not thread.is_alive(), 10, "uvicorn to start")
        assert server.started, f"uvicorn did not start on {host}:{port}"
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=5) as client:
            yield client
    finally:
        server.should_exit = True
        thread.join(timeout=10)


@pytest.fixture
def served_table():
    """A RoleTable behind the real FastAPI app on a real uvicorn thread (loopback); yields (table, client)."""
    table = RoleTable("run-1", gone_after_s=3.0)
    with serving(table) as client:
        yield table, client


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


# -- who may ask: the dashboard's token (dashboard/access.py) ------------------------------

BEARER = {"Authorization": f"Bearer {TOKEN}"}
#: every kind of route: the page, the JSON API, a static file, Prometheus, liveness
READ_ROUTES = ("/", "/api/status", "/api/history", "/api/episodes", "/api/qattention", "/static/app.js",
               "/static/vendor/uplot/uPlot.min.css", "/metrics", "/healthz")


def refused(answer: httpx.Response, why: str = "token required") -> bool:
    return answer.status_code == 401 and answer.json()["error"] == why and "Bearer" in answer.headers[
        "www-authenticate"]


@pytest.mark.parametrize("host, open_reads", [
    ("127.0.0.1", True), ("127.4.5.6", True), ("::1", True), ("[::1]", True), ("localhost", True),
    ("0.0.0.0", False), ("::", False), ("10.0.0.2", False), ("192.168.1.20", False), ("hub.lab", False),
])
def test_who_needs_the_token_depends_on_the_bound_interface(host, open_reads):
    access = Access(TOKEN, host)
    assert access.open_reads is open_reads
    assert access.needs_token("GET") is (not open_reads) and access.needs_token("HEAD") is (not open_reads)
    assert access.needs_token("POST") and access.needs_token("DELETE")  # a command always does
    assert access.accepts(TOKEN) and not access.accepts(TOKEN[:-1]) and not access.accepts(None)
    assert not access.accepts("") and not access.accepts(TOKEN + "x") and not access.accepts("é" * 43)


def test_on_loopback_reads_are_open_and_the_operator_commands_need_the_token(served_table, caplog):
    table, client = served_table
    for route in READ_ROUTES:
        assert client.get(route).status_code == 200, route  # as before: tests and local users read freely
    stop = "/api/operator/robot-0/stop"
    with caplog.at_level(logging.WARNING, logger="dashboard.access"):
        assert refused(client.post(stop))
        assert refused(client.post(stop, headers={"Authorization": "Bearer not-the-token"}), "wrong token")
        assert refused(client.post(stop, params={"token": TOKEN[:-1] + "?"}), "wrong token")
        assert refused(client.post(stop, headers={"Authorization": f"Basic {TOKEN}"}))  # only a bearer counts
    # past the token: the route itself answers (503: no operator session; 202 in test_robot_operator.py)
    assert client.post(stop, headers=BEARER).json()["detail"].startswith("the operator channel is not connected")
    assert client.post(stop, params={"token": TOKEN}).status_code == 503
    assert client.post(stop, headers={"authorization": f"bearer {TOKEN}"}).status_code == 503
    assert client.get("/api/status").json()["http_refused_token"] == 4
    lines = [r.getMessage() for r in caplog.records if r.name == "dashboard.access"]
    assert len(lines) == 1 and "refused 1 request" in lines[0] and "POST /api/operator/robot-0/stop" in lines[0]
    assert TOKEN not in client.get("/api/status").text  # what anyone on this machine reads never holds it


def test_bound_beyond_loopback_every_route_needs_the_token():
    """Bound to 0.0.0.0 (every interface), reached here through 127.0.0.1: no route answers without the token."""
    with serving(RoleTable("run-1"), host="0.0.0.0") as client:
        for route in READ_ROUTES:
            assert refused(client.get(route)), route
            assert refused(client.get(route, params={"token": "nope"}), "wrong token"), route
            assert client.get(route, headers=BEARER).status_code == 200, route
        assert refused(client.get("/no-such-route"))  # not even whether a route exists
        assert refused(client.post("/api/operator/robot-0/stop"))
        assert client.post("/api/operator/robot-0/stop", headers=BEARER).status_code == 503
        metrics = client.get("/metrics", headers=BEARER)  # how Prometheus scrapes it (authorization: credentials)
        assert metrics.text.startswith("# HELP") and metrics.headers["content-type"].startswith("text/plain")

        page = client.get("/", params={"token": TOKEN})  # how a person opens it: the URL the dashboard logs
        assert page.status_code == 200 and "api/status" in page.text
        cookie = page.headers["set-cookie"]  # for what the page loads by itself: <script>, <img>
        assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
        assert client.get("/static/app.js").status_code == 200  # httpx keeps the cookie, as a browser does
        assert refused(client.post("/api/operator/robot-0/stop"))  # a command never rides on the cookie
        client.cookies.clear()
        assert refused(client.get("/static/app.js"))
        status = client.get("/api/status", headers=BEARER).json()
        assert status["http_refused_token"] == 2 * len(READ_ROUTES) + 4


@pytest.mark.parametrize("fabric, security", [
    (FabricConfig(), "loopback"),
    (FabricConfig(insecure=True, listen=["tcp/0.0.0.0:7447"]), "insecure"),
    (FabricConfig(certs="/etc/c2farm-certs", listen=["tcp/0.0.0.0:7447"]), "tls"),
])
def test_the_page_and_the_status_say_how_secure_the_fabric_is(fabric, security):
    assert fabric_security(fabric) == security
    with serving(RoleTable("run-1"), fabric=security) as client:
        assert client.get("/api/status").json()["fabric_security"] == security
        page = client.get("/").text
        banner = FABRIC_BANNERS[security]
        if banner:
            assert f'data-security="{security}">{banner}</div>' in page.replace("&amp;", "&")
        else:
            assert 'data-security="loopback" hidden>' in page
    assert "INSECURE" in FABRIC_BANNERS["insecure"] and "plain TCP beyond loopback" in FABRIC_BANNERS["insecure"]
    assert FABRIC_BANNERS["tls"] == "fabric: TLS + access control"


def test_the_token_file_is_made_private_once_and_kept(tmp_path):
    path = token_path(tmp_path)
    assert path == tmp_path / TOKEN_FILE == tmp_path / "dashboard.token"
    assert token_path(tmp_path, str(tmp_path / "elsewhere")) == tmp_path / "elsewhere"
    token = ensure_token(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and len(token) >= 43
    assert ensure_token(path) == token  # a restarted dashboard keeps it: an open page goes on working
    assert [p.name for p in tmp_path.iterdir()] == [TOKEN_FILE]  # no temporary file left behind
    assert ensure_token(tmp_path / "b") != token  # fresh ones are random

    path.chmod(0o644)
    assert ensure_token(path) == token and stat.S_IMODE(path.stat().st_mode) == 0o600
    mine = tmp_path / "mine.token"
    mine.write_text("a-token-chosen-by-someone-123\n")
    assert ensure_token(mine) == "a-token-chosen-by-someone-123"
    for bad in ("", "short", "has a space in it, long enough", "semi;colon-is-not-allowed-here"):
        mine.write_text(bad)
        with pytest.raises(ValueError, match="not a dashboard token"):
            ensure_token(mine)


@pytest.mark.parametrize("shm", [False])
def test_the_dashboard_role_serves_with_its_run_token(router, tmp_path, caplog):
    """``c2farm dashboard`` as the launcher runs it: the token made in the run directory, its URL logged,
    kept across a restart; the fabric's security on the page."""
    config = DashboardConfig(port=get_free_port())

    def start(fabric: FabricConfig):
        from dashboard.service import run

        ctx = RoleContext("run-1", "dashboard", tmp_path, fabric=fabric)
        thread = threading.Thread(target=run, args=(config, ctx), daemon=True)
        thread.start()
        return ctx, thread

    with caplog.at_level(logging.INFO, logger="dashboard.service"):
        ctx, thread = start(router)
        try:
            url = wait_for(lambda: next((r.args for r in caplog.records if r.getMessage().startswith(
                "dashboard at")), None), 30, "the dashboard's URL in its log")
            token = (tmp_path / "dashboard.token").read_text().strip()
            assert stat.S_IMODE(os.stat(tmp_path / "dashboard.token").st_mode) == 0o600
            assert f"http://127.0.0.1:{config.port}/?token={token}" in caplog.text
            assert url[1] == config.port and str(tmp_path / "dashboard.token") in caplog.text
            with httpx.Client(base_url=f"http://127.0.0.1:{config.port}", timeout=5) as http:
                assert http.get("/api/status").json()["fabric_security"] == "loopback"
                assert refused(http.post("/api/operator/robot-0/stop"))
                answer = http.post("/api/operator/robot-0/stop", headers={"Authorization": f"Bearer {token}"})
                assert answer.status_code == 202 and answer.json()["seq"] == 1  # on the fabric
                wait_for(lambda: (d := _dashboard_row(http)) and d["counters"].get("http_refused_token") == 1, 20,
                         "the dashboard's own heartbeat to count the refusal")
        finally:
            ctx.stop.set()
            thread.join(timeout=20)
        caplog.clear()
        ctx, thread = start(dataclasses.replace(router, insecure=True))  # restarted: same token, insecure fabric
        try:
            wait_for(lambda: "dashboard at" in caplog.text, 30, "the restarted dashboard's URL")
            assert f"?token={token}" in caplog.text and Path(tmp_path / "dashboard.token").read_text().strip() == token
            with httpx.Client(base_url=f"http://127.0.0.1:{config.port}", timeout=5) as http:
                assert http.get("/api/status").json()["fabric_security"] == "insecure"
                assert "fabric: INSECURE" in http.get("/").text
        finally:
            ctx.stop.set()
            thread.join(timeout=20)


def _dashboard_row(http: httpx.Client) -> dict | None:
    return next((r for r in http.get("/api/status").json()["roles"] if r["role"] == "dashboard"), None)
