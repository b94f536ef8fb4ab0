"""Fault injection on one live `c2farm launch`: every role SIGKILLed in turn (the router too),
a SIGSTOPped learner, the acknowledged-episodes ledger, a hostile flood on every key and the
sample endpoint (bench/hostile.py), and a clean stop under load.

One launcher run serves the whole file (starting torch roles is the slow part on 2 cores);
the tests run in file order and share it. Every wait is a correctness timeout, generous so
a busy machine does not fail it; the times it took are printed (run with -s to see them).
"""

from __future__ import annotations

import importlib.util
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import psutil
import pytest
from conftest import REPO, TINY_TRAINING, Descendants, get_free_port, kill_launcher, survivors, wait_for
from synthetic_episodes import synthetic_episode

from protocol import keys
from protocol.codec import payload_digest
from protocol.episode import Episode
from protocol.episode_outbox import Outbox
from protocol.fabric import FabricConfig, open_session
from protocol.messages import AckStatus, EpisodeAck, decode, encode

_spec = importlib.util.spec_from_file_location("hostile", REPO / "bench" / "hostile.py")
hostile = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(hostile)

# One launcher run for the file: its start (torch in every role) counts against the first test.
pytestmark = pytest.mark.timeout(1800)

ROLES = ("router", "replay", "dashboard", "learner", "actor-0")
BACK_S = 300.0  #: a killed role is alive again (torch roles reimport torch) within this
#: launch.liveness_timeout_s / liveness_grace_s for this run (a restarted torch role beats within the grace)
TIMEOUT_S, GRACE_S = 10.0, 60.0
SMALL_RUN = [
    "--task", "reach_target", "--actors", "1",
    "--set", "launch.roles=[router,replay,dashboard,learner,actor]",
    "--set", "sim.image_size=64",
    "--set", "demos.episodes=0",
    *TINY_TRAINING,
    "--set", "actor.resend_after_s=2",  # resend soon after the replay or the router comes back
    "--set", "launch.restart_backoff_s=0.5",
    "--set", "launch.progress_every_s=0",
    "--set", f"launch.liveness_timeout_s={TIMEOUT_S}",
    "--set", f"launch.liveness_grace_s={GRACE_S}",
]


class LiveRun:
    """The launcher process, its output, the dashboard's view, and what actors were acked."""

    def __init__(self, tmp: Path):
        self.ports = {name: get_free_port() for name in ("router", "dashboard", "zmq")}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "deploy.cli", "launch", "--run-id", "faults", "--runs-dir", str(tmp),
             "--router-port", str(self.ports["router"]), "--dashboard-port", str(self.ports["dashboard"]),
             "--set", f"replay.zmq_endpoint=tcp://127.0.0.1:{self.ports['zmq']}", *SMALL_RUN],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        )
        self.lines: list[str] = []
        threading.Thread(target=lambda: self.lines.extend(line.rstrip() for line in self.proc.stdout),
                         daemon=True).start()
        self.children = Descendants(self.proc.pid)
        self.http = httpx.Client(base_url=f"http://127.0.0.1:{self.ports['dashboard']}", timeout=3)
        self.acked: dict[int, float] = {}  #: actor pid -> most episodes it reported acknowledged (stored)

    def status(self) -> dict:
        """instance -> role row of /api/status ({} while the dashboard is down)."""
        self.children.scan()
        try:
            rows = {r["instance"]: r for r in self.http.get("/api/status").json()["roles"]}
        except (httpx.HTTPError, ValueError, KeyError):
            return {}
        for row in rows.values():
            if row["role"] == "actor" and row["pid"]:
                self.acked[row["pid"]] = max(self.acked.get(row["pid"], 0), row["counters"].get("acked", 0))
        return rows

    def alive(self, *names: str) -> dict:
        """The status if every named instance is alive, else {}."""
        rows = self.status()
        return rows if all(rows.get(n, {}).get("alive") and rows[n]["pid"] for n in names) else {}

    def counter(self, rows: dict, instance: str, name: str) -> float:
        return rows.get(instance, {}).get("counters", {}).get(name, -1)

    def wait_training(self, after: dict, what: str) -> dict:
        """Wait until the learner has updated past ``after``'s count and the actor was acked more."""
        updates, acked = self.counter(after, "learner", "updates"), sum(self.acked.values())
        return wait_for(
            lambda: (s := self.alive(*ROLES)) and self.counter(s, "learner", "updates") > updates
            and sum(self.acked.values()) > acked and s,
            BACK_S, f"training to go on after {what}", interval=0.5,
        )

    def close(self) -> None:
        self.http.close()
        kill_launcher(self.proc, self.children)


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    run = LiveRun(tmp_path_factory.mktemp("faults"))
    try:
        wait_for(lambda: (s := run.alive(*ROLES)) and run.counter(s, "learner", "updates") >= 2
                 and run.counter(s, "actor-0", "weights_version") >= 2 and sum(run.acked.values()) >= 1,
                 600, "every role alive, the learner updating and the actor on trained weights", interval=0.5)
        yield run
    finally:
        run.close()


def test_every_role_sigkilled_in_turn_comes_back_and_training_goes_on(live):
    for name in ROLES:
        before = wait_for(lambda: live.alive(*ROLES), BACK_S, f"every role alive before killing {name}", interval=0.5)
        victim = before[name]["pid"]
        assert victim in live.children.seen, f"{name} (pid {victim}) is not one of the launcher's processes"
        t0 = time.monotonic()
        os.kill(victim, signal.SIGKILL)
        back = wait_for(lambda: (s := live.alive(*ROLES)) and s[name]["pid"] != victim and s,
                        BACK_S, f"{name} to be restarted", interval=0.2)
        seconds = time.monotonic() - t0
        others = {n: back[n]["pid"] for n in ROLES if n != name}
        assert others == {n: before[n]["pid"] for n in others}, "a kill took another role down"
        if name == "replay":  # restored from its write-ahead log: every acked episode is still there
            assert back[name]["counters"]["size_episodes"] >= before[name]["counters"]["size_episodes"]
        if name == "router":  # everyone reconnected: episodes reach the replay, weights the actor
            version = live.counter(before, "actor-0", "weights_version")
            wait_for(lambda: live.counter(live.alive(*ROLES), "actor-0", "weights_version") > version,
                     BACK_S, "new weights to reach the actor through the restarted router", interval=0.5)
        live.wait_training(before, f"the {name} kill")
        print(f"{name}: back in {seconds:.1f} s, training on after {time.monotonic() - t0:.1f} s")
    text = "\n".join(live.lines)
    for name in ROLES:
        assert f"{name} exited with code -9; restart" in text


def test_a_stopped_learner_is_killed_and_replaced(live):
    before = wait_for(lambda: live.alive(*ROLES), BACK_S, "every role alive", interval=0.5)
    victim = before["learner"]["pid"]
    os.kill(victim, signal.SIGSTOP)
    t0 = time.monotonic()
    try:
        killed = re.compile(rf"learner \(pid {victim}\) silent for \d+ s")
        wait_for(lambda: any(killed.search(line) for line in live.lines), GRACE_S + TIMEOUT_S + 60,
                 "the launcher to kill the silent learner", interval=0.5)
        print(f"stopped learner killed after {time.monotonic() - t0:.1f} s")
        assert wait_for(
            lambda: not psutil.pid_exists(victim) or psutil.Process(victim).status() == psutil.STATUS_ZOMBIE,
            10,
            "the stopped learner to be gone",
        )
        wait_for(lambda: (s := live.alive(*ROLES)) and s["learner"]["pid"] != victim, BACK_S,
                 "a new learner", interval=0.5)
        live.wait_training(before, "the stopped learner")
        print(f"new learner training after {time.monotonic() - t0:.1f} s")
    finally:
        if psutil.pid_exists(victim):
            try:
                os.kill(victim, signal.SIGKILL)
            except ProcessLookupError:
                pass


def test_no_acknowledged_episode_is_lost(live):
    live.wait_training(wait_for(lambda: live.alive(*ROLES), BACK_S, "every role alive", interval=0.5), "the faults")
    acked = sum(live.acked.values())
    assert len(live.acked) >= 2, "the actor was killed once, so two actor processes reported acks"
    # The replay's status may lag the actor's by a heartbeat: wait for it to catch up.
    stored = wait_for(
        lambda: (s := live.alive("replay")) and s["replay"]["counters"]["size_episodes"] >= acked and s,
        30, f"the replay to hold the {acked:.0f} episodes its actors were acknowledged", interval=0.5,
    )["replay"]["counters"]
    assert stored["episodes_evicted"] == 0  # nothing left by eviction either, so the count is the ledger
    print(f"acknowledged to actors: {acked:.0f}, stored: {stored['size_episodes']:.0f}")


def test_a_flood_on_every_key_crashes_nothing_is_counted_and_training_goes_on(live):
    """bench/hostile.py's flood, 5 rounds of every hostile kind on every key and the sample endpoint."""
    before = wait_for(lambda: live.alive(*ROLES), BACK_S, "every role alive", interval=0.5)
    endpoint = f"tcp/127.0.0.1:{live.ports['router']}"
    session = open_session(FabricConfig(connect=[endpoint], listen=[endpoint]))
    try:
        captured = hostile.capture(session, "faults")
        time.sleep(2.0)  # a heartbeat after the capture: counts from here on are the flood's
        before = live.alive(*ROLES)
        sent = hostile.flood(session, "faults", f"tcp://127.0.0.1:{live.ports['zmq']}", captured, rounds=5)
    finally:
        session.close()
    after = live.wait_training(before, "the flood")
    assert {n: after[n]["pid"] for n in ROLES} == {n: before[n]["pid"] for n in ROLES}, "a message took a role down"
    # every hostile message is counted by its receiver (real traffic may add to the counts)
    for target in hostile.RECEIVERS:
        n = sum(v for (t, _), v in sent.items() if t == target)
        wait_for(lambda: hostile.counted(live.alive(*ROLES), target) - hostile.counted(before, target) >= n,
                 30, f"{target}: {n} hostile messages counted", interval=0.5)
    learner = live.alive(*ROLES)["learner"]["counters"]
    assert learner["weights_refused"] == 0 and learner["checkpoints_refused"] == 0  # weights stayed finite
    replay = live.alive(*ROLES)["replay"]["counters"]
    assert replay["ingest_rejected_nonfinite"] >= 5 and replay["ingest_rejected_impersonation"] >= 5


def test_a_clean_stop_under_load_is_quick_and_leaves_nothing_behind(live):
    busy = wait_for(lambda: live.alive(*ROLES), BACK_S, "every role alive", interval=0.5)
    live.wait_training(busy, "the previous tests")  # learner and actor are mid-work right now
    live.children.scan()
    t0 = time.monotonic()
    live.proc.send_signal(signal.SIGTERM)
    assert live.proc.wait(timeout=30) == 0
    seconds = time.monotonic() - t0
    left = survivors(live.children.processes)
    ends = ("all roles stopped in", "did not stop", "still dying")
    stopped = [line for line in live.lines if any(end in line for end in ends)]
    print(f"clean stop took {seconds:.1f} s: {stopped}")
    assert not left, f"left behind: {left}"
    assert seconds < 10.0, stopped


def test_a_full_outbox_keeps_resending_while_it_waits_for_room():
    """After a replay or router restart the actor's outbox is full of episodes nobody will ack
    unless they are sent again; waiting for room without resending stalled actors for
    ``outbox_wait_s`` and then dropped an episode (seen on this file's live run)."""
    endpoint = f"tcp/127.0.0.1:{get_free_port()}"
    fabric = FabricConfig(connect=[endpoint], listen=[endpoint])
    router = open_session(fabric, "router")
    replay, actor = open_session(fabric), open_session(fabric)
    seen: dict[int, int] = {}

    def lossy_replay(sample) -> None:  # the first copy of every episode is lost, a resend is acked
        episode = decode(sample.payload.to_bytes(), expect=Episode)
        seen[episode.episode_id] = seen.get(episode.episode_id, 0) + 1
        if seen[episode.episode_id] > 1:
            ack = EpisodeAck(episode.actor_id, episode.episode_id, AckStatus.STORED,
                             digest=payload_digest(sample.payload.to_bytes()))
            replay.put(keys.acks("ob", episode.actor_id), encode(ack))

    subscriber = replay.declare_subscriber(keys.episodes("ob"), lossy_replay)
    outbox = Outbox(actor, "ob", "actor-0", size=2, resend_after_s=0.3, wait_s=60.0)
    try:
        time.sleep(0.5)  # let the subscriptions reach the router
        for i in range(4):
            outbox.send(synthetic_episode(steps=2, size=8, episode_id=i))
        assert outbox.flush(timeout_s=30)
        assert outbox.counters["dropped"] == 0 and outbox.counters["acked"] == 4
    finally:
        outbox.close()
        subscriber.undeclare()
        for session in (actor, replay, router):
            session.close()


def test_a_full_outbox_stops_waiting_when_its_role_is_told_to_stop():
    """Nobody acks (the replay refuses a restarted actor's id for a while, or is down): a send
    on a full outbox waited ``outbox_wait_s`` (30 s), past the launcher's grace, and got the
    actor SIGKILLed on a clean stop (measured by bench/bench_reliability.py)."""
    endpoint = f"tcp/127.0.0.1:{get_free_port()}"
    fabric = FabricConfig(connect=[endpoint], listen=[endpoint])
    router = open_session(fabric, "router")
    actor = open_session(fabric)
    stop = threading.Event()
    outbox = Outbox(actor, "ob", "actor-0", size=1, resend_after_s=0.3, wait_s=60.0, stop=stop)
    try:
        outbox.send(synthetic_episode(steps=2, size=8, episode_id=0))
        threading.Timer(0.5, stop.set).start()
        t0 = time.monotonic()
        outbox.send(synthetic_episode(steps=2, size=8, episode_id=1))  # full: waits until stop
        assert time.monotonic() - t0 < 30  # correctness bound: far below wait_s
        assert outbox.counters["dropped"] == 0 and outbox.pending == 2
    finally:
        outbox.close()
        actor.close()
        router.close()


def test_an_ack_for_another_payload_never_retires_an_episode():
    """A forger that did not see the episode (or a stale ack of an earlier payload with the
    same id) acks it "stored": the outbox counts it, keeps the episode and resends it until
    the replay's real ack, which names the payload's digest, arrives."""
    endpoint = f"tcp/127.0.0.1:{get_free_port()}"
    fabric = FabricConfig(connect=[endpoint], listen=[endpoint])
    router = open_session(fabric, "router")
    replay, forger, actor = open_session(fabric), open_session(fabric), open_session(fabric)
    received: list[bytes] = []
    subscriber = replay.declare_subscriber(keys.episodes("ob"), lambda s: received.append(s.payload.to_bytes()))
    outbox = Outbox(actor, "ob", "actor-0", size=4, resend_after_s=0.3, wait_s=60.0)
    try:
        time.sleep(0.5)  # let the subscriptions reach the router
        outbox.send(synthetic_episode(steps=2, size=8, episode_id=7))
        forged = EpisodeAck("actor-0", 7, AckStatus.STORED, digest="0" * 16)
        for _ in range(3):
            forger.put(keys.acks("ob", "actor-0"), encode(forged))
        wait_for(lambda: outbox.counters["forged_acks"] == 3, 10, "the forged acks to arrive")
        assert outbox.pending == 1 and outbox.counters["acked"] == 0
        time.sleep(0.4)
        assert outbox.resend_due() == 1  # still pending, so still resent
        wait_for(lambda: received, 10, "the episode to reach the replay")
        real = EpisodeAck("actor-0", 7, AckStatus.STORED, digest=payload_digest(received[0]))
        replay.put(keys.acks("ob", "actor-0"), encode(real))
        assert outbox.flush(timeout_s=10) and outbox.counters["acked"] == 1
    finally:
        outbox.close()
        subscriber.undeclare()
        for session in (actor, forger, replay, router):
            session.close()
