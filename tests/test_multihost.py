"""docs/multi-machine.md run for real: a hub and three other "machines" (network namespaces on a bridge).

- hub: ``c2farm launch --listen tcp/<hub>:7447 --actors 0``: router, replay (ZeroMQ bound on
  0.0.0.0), dashboard, demo source, evaluator. The learner is not here: it runs on a host of its
  own, the recipe's second arrangement, so one run checks both (starting torch roles is the
  slow part on 2 cores);
- learner: ``c2farm launch --roles learner --connect tcp/<hub>:7447`` dialling the replay's
  ZeroMQ endpoint across the bridge (``learner.replay_endpoint=tcp://<hub>:5560``);
- box1, box2: ``c2farm launch --roles actor --actors 1 --connect tcp/<hub>:7447
  --set launch.instance_prefix=boxN-``; box2 dials a delay proxy on its own 127.0.0.1 (nothing else
  listens there) that adds DELAY_MS each way on the way to the hub: a far-away machine, since the
  kernel here has no netem.

Every host passes ``--certs`` (keys made by ``c2farm certs`` with the hub's address): Zenoh over
TLS with mutual authentication and the router's access control, CURVE between the learner host
and the replay, the recipe's secure variant.

Each host has its own runs directory and /dev/shm, as separate machines would, so every byte
between them crosses a veth. The tests run in file order on that one run: the recipe works,
the learner trains across the bridge, box1's cable is pulled for CUT_S seconds and plugged back
(box1 resends, catches up on weights, box2 carries on), the router is restarted, an intruder host
tries what a stolen actor certificate allows, box2 vanishes for good, and every host left stops
cleanly with every acknowledged episode in the replay. Figures (reconnect times, bytes per episode, episodes/s
across a veth) are printed: run with -s to read them.
"""

from __future__ import annotations

import http.client
import json
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import psutil
import pytest
from conftest import REPO, TINY_TRAINING, wait_for

from deploy.certs import CertsPlan, make_certs
from harness import Faults, Started, Topology, probe
from protocol.weights_follower import REASONS
from replay_server.checkpoint_files import load_latest

WHY_NOT = probe()
pytestmark = [pytest.mark.skipif(WHY_NOT is not None, reason=f"no network namespaces here: {WHY_NOT}"),
              pytest.mark.timeout(1800)]  # one run for the file: its start counts against the first test

RUN_ID = "multihost"
BOXES = ("box1", "box2")
ROUTER_PORT, ZMQ_PORT, DASHBOARD_PORT = 7447, 5560, 8080  # every namespace has ports of its own
#: How long box1's cable is out at least: well past Zenoh's 10 s lease, so the router drops box1's
#: session and box1 must redial. Longer on a machine so slow that box1 would finish no episode within
#: it (see the test).
CUT_S = 30.0
MAX_CUT_S = 120.0
DELAY_MS = 50  #: one-way delay box2's link gets from harness.delay_proxy
INTRUDER = "intruder"  #: a host on the network that runs none of ours: tests/hostile_client.py
START_S = 900.0  #: a correctness timeout for the first episodes and weights (torch loads in every role)

#: Settings every host passes (the networks must agree, or weights would not fit the actors').
SMALL = [
    "--task", "reach_target",
    "--set", "sim.image_size=64",
    "--set", "demos.episodes=2",
    *TINY_TRAINING,
    "--set", "actor.eval_episodes=1",
    "--set", "actor.eval_every_versions=1000",  # one evaluation, then it idles: the CPU is the actors'
    "--set", "actor.record_eval=false",
    "--set", "actor.resend_after_s=3",  # resend soon after the cable is back
    "--set", "actor.outbox_size=64",  # room for what a 30 s cut holds back (16 fill in about 20 s here)
    "--set", "launch.restart_backoff_s=1",
    "--set", "launch.progress_every_s=0",
    "--set", "launch.router_wait_s=120",  # a starved machine can take more than the default 20 s to start the router
]


def c2farm(*args: str) -> list[str]:
    return [sys.executable, "-m", "deploy.cli", *args]


def trust(root: Path) -> list[str]:
    """What every host passes to be trusted beyond loopback: the recipe's secure variant, keys made by
    `c2farm certs` on the hub (every host here reads the one directory; real hosts get only their files)."""
    return ["--certs", str(root / "certs")]


def make_keys(topology: Topology, root: Path) -> None:
    """`c2farm certs certs/ --hub <hub> --identity ...`: the hub's roles, the learner host, both boxes."""
    make_certs(CertsPlan(root / "certs", hubs=[topology.hub.ip], actors=0,
                         extra=[f"actor.{box}-actor-0" for box in BOXES]))


# The launch commands of each kind of machine, in one place.


def hub_command(topology: Topology, root: Path) -> list[str]:
    return c2farm(
        "launch", "--run-id", RUN_ID, "--runs-dir", str(root / "hub" / "runs"),
        "--listen", f"tcp/{topology.hub.ip}:{ROUTER_PORT}", "--actors", "0",
        "--roles", "router,replay,dashboard,demo_source,eval", "--dashboard-port", str(DASHBOARD_PORT),
        "--set", f"replay.zmq_endpoint=tcp://0.0.0.0:{ZMQ_PORT}",
        "--set", f"demos.directory={root / 'hub' / 'demos'}", *trust(root), *SMALL,
    )


def learner_command(topology: Topology, root: Path) -> list[str]:
    return c2farm(
        "launch", "--run-id", RUN_ID, "--runs-dir", str(root / "learner" / "runs"), "--roles", "learner",
        "--connect", f"tcp/{topology.hub.ip}:{ROUTER_PORT}",
        "--set", f"learner.replay_endpoint=tcp://{topology.hub.ip}:{ZMQ_PORT}", *trust(root), *SMALL,
    )


def actor_command(topology: Topology, root: Path, box: str, router: str) -> list[str]:
    """``router``: the HOST:PORT box dials (the hub's, or a proxy's in front of it)."""
    return c2farm(
        "launch", "--run-id", RUN_ID, "--runs-dir", str(root / box / "runs"), "--roles", "actor", "--actors", "1",
        "--connect", f"tcp/{router}", "--set", f"launch.instance_prefix={box}-", *trust(root), *SMALL,
    )


def delay_proxy_command(listen: str, target: str) -> list[str]:
    return [sys.executable, "-m", "harness.delay_proxy", "--listen", listen, "--target", target,
            "--delay-ms", str(DELAY_MS)]


@dataclass
class Cluster:
    """The bench, the launcher of each host, and the dashboard's view from inside the hub."""

    topology: Topology
    faults: Faults
    root: Path
    launchers: dict[str, Started] = field(default_factory=dict)
    vanished: set[str] = field(default_factory=set)  #: boxes gone for good (test_a_host_that_vanishes...)
    started_at: float = field(default_factory=time.monotonic)

    def status(self) -> dict:
        """The hub dashboard's /api/status as {instance: row, "summary": ...}; {} while it does not answer."""
        try:
            with self.topology.inside("hub"):  # the dashboard binds the hub's 127.0.0.1
                conn = http.client.HTTPConnection("127.0.0.1", DASHBOARD_PORT, timeout=5)
                conn.request("GET", "/api/status")
                body = conn.getresponse().read()
                conn.close()
            snap = json.loads(body)
            return {"summary": snap["summary"], **{row["instance"]: row for row in snap["roles"]}}
        except (OSError, ValueError, KeyError, http.client.HTTPException):
            return {}

    def counters(self, instance: str) -> dict:
        return self.status().get(instance, {}).get("counters", {})

    def actor(self, box: str) -> str:
        return f"{box}-actor-0"

    def replay_stores_at_least(self, episodes: float, timeout: float = 30.0) -> dict:
        """Wait until the replay reports ``episodes`` stored: its status and the actors' are published apart,
        so one snapshot may show an actor's ack before the replay's count that includes it."""
        return wait_for(lambda: (c := self.counters("replay")).get("episodes_stored", 0) >= episodes and c, timeout,
                        f"the replay to report {episodes:.0f} episodes stored", interval=0.5)

    def acked(self, status: dict) -> float:
        """Episodes the replay acknowledged as stored to the remote actors and the demo source, in ``status``."""
        return sum(status.get(name, {}).get("counters", {}).get("acked", 0)
                   for name in ("demos", *map(self.actor, BOXES)))

    def elapsed(self) -> float:
        return time.monotonic() - self.started_at

    def logs(self) -> str:
        """Every launcher's tail, for a failure message."""
        return "\n".join(f"--- {name} ---\n{s.output()[-3000:]}" for name, s in self.launchers.items())


def describe(pids: list[int]) -> list[str]:
    out = []
    for pid in pids:
        try:
            out.append(f"{pid}: {' '.join(psutil.Process(pid).cmdline())[:200]}")
        except psutil.NoSuchProcess:
            pass
    return out


@pytest.fixture(scope="module")
def cluster(tmp_path_factory) -> Iterator[Cluster]:
    root = tmp_path_factory.mktemp("multihost")
    with Topology(["learner", *BOXES, INTRUDER], root / "logs") as topology:
        make_keys(topology, root)
        run = Cluster(topology, Faults(topology), root)
        run.launchers["hub"] = topology.spawn("hub", hub_command(topology, root), "launch", cwd=REPO)
        topology.wait_listening("hub", topology.hub.ip, ROUTER_PORT, timeout=120, process=run.launchers["hub"])
        run.launchers["learner"] = topology.spawn("learner", learner_command(topology, root), "launch", cwd=REPO)
        hub_router = f"{topology.hub.ip}:{ROUTER_PORT}"
        proxy = topology.spawn("box2", delay_proxy_command(f"127.0.0.1:{ROUTER_PORT}", hub_router), "delay-proxy",
                               cwd=REPO)
        run.launchers["box2-proxy"] = proxy
        topology.wait_listening("box2", "127.0.0.1", ROUTER_PORT, timeout=60, process=proxy)
        routers = {"box1": hub_router, "box2": f"127.0.0.1:{ROUTER_PORT}"}
        for box in BOXES:
            run.launchers[box] = topology.spawn(box, actor_command(topology, root, box, routers[box]), "launch",
                                                cwd=REPO)
        yield run
        # leaving the bench kills whatever a failed test left running and deletes the namespaces


def test_the_recipe_stores_episodes_from_both_remote_hosts_and_weights_reach_them(cluster: Cluster):
    def ready():
        s = cluster.status()
        rows = [s.get(cluster.actor(box), {}) for box in BOXES]
        return s if all(r.get("alive") and r["counters"].get("acked", 0) >= 2
                        and r["counters"].get("weights_version", 0) >= 2 for r in rows) else None

    try:
        s = wait_for(ready, START_S, "episodes acknowledged from box1 and box2 and weights version 2 at both",
                     interval=1.0)
    except AssertionError as exc:
        raise AssertionError(f"{exc}\n{cluster.logs()}") from None
    print(f"\nfirst episodes from both boxes stored and weights v>=2 at both after {cluster.elapsed():.0f} s")
    # the replay stored what each remote actor (and the demo source) was told was stored
    cluster.replay_stores_at_least(cluster.acked(s))
    assert {"router", "replay", "dashboard", "learner", *map(cluster.actor, BOXES)} <= set(s)
    assert "actor-0" not in s  # every actor carries its machine's prefix
    for box in BOXES:
        row = s[cluster.actor(box)]
        link = cluster.topology.link_counters(box)
        per_episode = link["sent_bytes"] / max(1, row["counters"]["sent"])
        print(f"{box}: {row['counters']['acked']:.0f} episodes acked, weights v{row['counters']['weights_version']:.0f}"
              f" (last one {row['counters'].get('weights_latency_s', float('nan')) * 1e3:.0f} ms after the learner "
              f"published it), {link['sent_bytes'] / 1e6:.1f} MB sent / {link['received_bytes'] / 1e6:.1f} MB "
              f"received over its veth ({per_episode / 1e3:.0f} kB sent per episode)")
        # the episodes crossed the veth: no shared memory between machines
        assert link["sent_bytes"] >= 10_000 * row["counters"]["acked"]
        assert link["received_bytes"] > 0 and row["counters"]["weights_version"] >= 2


def test_the_learner_on_its_own_host_trains_from_the_replay_across_the_bridge(cluster: Cluster):
    first = wait_for(lambda: (c := cluster.counters("learner")).get("updates", 0) >= 6 and c, START_S,
                     "the learner on its own host to update from the replay's batches", interval=1.0)
    link_before = cluster.topology.link_counters("learner")
    later = wait_for(lambda: (c := cluster.counters("learner")).get("updates", 0) > first["updates"] + 4 and c, 120,
                     "the learner's updates to keep advancing", interval=1.0)
    link_after = cluster.topology.link_counters("learner")
    replay = cluster.status()["replay"]
    print(f"\nlearner on {cluster.topology.host('learner').ip}: {later['updates']:.0f} updates, weights "
          f"v{later['weights_version']:.0f}; replay served {replay['counters']['batches_served']:.0f} batches on "
          f"{replay['info'].get('zmq_endpoint')}; the learner's veth carried "
          f"{(link_after['received_bytes'] - link_before['received_bytes']) / 1e3:.0f} kB in while it did "
          f"{later['updates'] - first['updates']:.0f} updates")
    assert replay["counters"]["batches_served"] >= later["updates"] - 1  # each update is one served batch
    assert link_after["received_bytes"] > link_before["received_bytes"]  # the batches came across the bridge
    assert later["weights_version"] > first.get("weights_version", 0)


def episode_period(cluster: Cluster, instance: str, timeout: float = 600.0) -> float:
    """Seconds between two episodes ``instance`` sends (timed from its status, to about a second);
    returns right after it sent one."""
    marks: list[float] = []
    last = None
    deadline = time.monotonic() + timeout
    while len(marks) < 2:
        assert time.monotonic() < deadline, f"{instance} sent no two episodes in {timeout:.0f} s"
        sent = cluster.counters(instance).get("sent")
        if sent is not None and last is not None and sent > last:
            marks.append(time.monotonic())
        last = sent if sent is not None else last
        time.sleep(0.25)
    return marks[1] - marks[0]


def test_a_pulled_cable_loses_no_acknowledged_episode_and_the_host_catches_up(cluster: Cluster):
    box1, box2 = (cluster.actor(box) for box in BOXES)
    # Cut right after box1 sent an episode, for long enough that it sends at least one more into the
    # cut (2.5 of its episode periods): that one is lost with the session and must be resent.
    period = episode_period(cluster, box1)
    cut_for = min(MAX_CUT_S, max(CUT_S, 2.5 * period))
    before = cluster.status()
    b1, b2 = before[box1]["counters"], before[box2]["counters"]

    cluster.faults.cut("box1")
    cut_at = time.monotonic()
    gone_after = dropped_after = None
    try:
        # and longer (bounded) on a machine so slow that box2 finished no episode in that time
        while (elapsed := time.monotonic() - cut_at) < cut_for or (
                elapsed < cut_for + 60 and cluster.counters(box2).get("acked", 0) <= b2["acked"]):
            s = cluster.status()
            if gone_after is None and s and not s[box1]["alive"]:
                gone_after = elapsed  # its statuses stopped coming (the dashboard's gone_after_s)
            if dropped_after is None and s and s[box1]["token"] is False:
                dropped_after = elapsed  # the router closed its session: Zenoh's lease ran out
            time.sleep(0.5)
        during = cluster.status()
    finally:
        cluster.faults.restore("box1")
    restored_at = time.monotonic()
    cut_s = restored_at - cut_at
    learner_version = during["learner"]["counters"]["weights_version"]

    # box2 kept storing while box1 was off the network; the hub saw box1 go
    assert during[box2]["counters"]["acked"] > b2["acked"]
    assert gone_after is not None and not during[box1]["alive"]

    back_after = wait_for(lambda: cluster.status().get(box1, {}).get("alive") and time.monotonic() - restored_at,
                          120, "box1 to be back on the dashboard", interval=0.5)
    caught_up = wait_for(
        lambda: (c := cluster.counters(box1)) and c["acked"] > b1["acked"] and c["outbox_pending"] == 0
        and c["weights_version"] >= learner_version and c,
        180, "box1 to deliver what it held and catch up on weights", interval=1.0,
    )
    caught_up_after = time.monotonic() - restored_at
    after = cluster.status()
    stored_during = during[box2]["counters"]["acked"] - b2["acked"]
    dropped = f"{dropped_after:.1f} s" if dropped_after is not None else "never"
    print(f"\nbox1 sent an episode every {period:.1f} s; cut its cable for {cut_s:.0f} s: the dashboard showed it "
          f"gone after {gone_after:.1f} s, the router dropped its session (liveliness token) after {dropped}; back on "
          f"the dashboard {back_after:.1f} s after the restore; outbox empty and weights "
          f"v{caught_up['weights_version']:.0f} (learner v{learner_version:.0f} at the restore) after "
          f"{caught_up_after:.1f} s; box1 sent {caught_up['sent'] - b1['sent']:.0f} episodes since the cut, resent "
          f"{caught_up['resent'] - b1['resent']:.0f} times, {caught_up['duplicates'] - b1['duplicates']:.0f} acked "
          f"as duplicates; box2 stored {stored_during:.0f} during the cut ({stored_during / cut_s:.2f} episodes/s)")
    assert after[box1]["pid"] == before[box1]["pid"]  # the same actor process rode out the cut
    assert caught_up["resent"] > b1["resent"]  # the outbox resent what the cut swallowed
    assert caught_up["dropped"] == 0  # nothing was pushed out of a full outbox unacknowledged
    cluster.replay_stores_at_least(cluster.acked(after))


def test_a_restarted_router_is_rejoined_by_every_remote_session_by_itself(cluster: Cluster):
    """The hub's router is killed; its launcher starts it again and every remote role redials (over TLS)."""
    topology = cluster.topology
    router = next(p for p in map(psutil.Process, topology.pids("hub")) if "router" in p.cmdline()[3:5])
    before = cluster.status()
    actors = [cluster.actor(box) for box in BOXES]
    router.kill()
    killed_at = time.monotonic()

    def rejoined():
        s = cluster.status()
        ok = s and s.get("router", {}).get("pid") not in (None, router.pid) and all(
            s.get(a, {}).get("alive") and s[a]["counters"].get("acked", 0) > before[a]["counters"]["acked"]
            for a in actors) and s["learner"]["counters"].get("weights_version", 0) > 0
        return s if ok else None

    after = wait_for(rejoined, 300, "both remote actors storing episodes again through the restarted router",
                     interval=0.5)
    print(f"\nrouter killed; both remote actors had new episodes acknowledged {time.monotonic() - killed_at:.1f} s "
          f"later (the launcher restarts it after launch.restart_backoff_s)")
    for a in actors:
        assert after[a]["pid"] == before[a]["pid"]  # the same processes: they redialled, nobody restarted them
        assert after[a]["losses"] == before[a]["losses"]  # the dashboard does not count a cut link as a death
        assert after[a]["link_losses"] >= 1
    assert after["router"]["losses"] >= 1  # the router itself did die


def test_an_intruder_with_a_stolen_actor_certificate_gets_nothing_in_or_out(cluster: Cluster):
    """An intruder host holds box1's certificate (copied off it) and the replay's public CURVE key."""
    hub, certs = cluster.topology.hub.ip, cluster.root / "certs"
    # At an actor, the forged weights would be a decode error and the forged learner status a bad announcement.
    # Not compared: ``not_announced`` and ``older``, which the learner's own versions can raise when its heartbeat
    # (sent with congestion control DROP) is dropped or overtaken; the actor then fetches the version it missed.
    forgery_counters = [f"weights_rejected_{reason}" for reason in REASONS if reason not in ("not_announced", "older")]
    forgery_counters.append("weights_bad_announcements")

    def up(s: dict) -> bool:  # run alone, this test may come before the cluster is: what it compares must be there
        actors = [s.get(cluster.actor(box), {}).get("counters", {}) for box in BOXES]
        return {"replay", "dashboard", "learner"} <= set(s) and all(set(forgery_counters) <= set(c) for c in actors)

    before = wait_for(lambda: up(s := cluster.status()) and s, START_S, "every role's counters on the hub's dashboard",
                      interval=1.0)
    report = json.loads(cluster.topology.run(INTRUDER, [
        sys.executable, str(REPO / "tests" / "hostile_client.py"), "--router", f"tcp/{hub}:{ROUTER_PORT}",
        "--replay", f"tcp://{hub}:{ZMQ_PORT}", "--run", RUN_ID, "--certs", str(certs),
        "--stolen", f"actor.{cluster.actor('box1')}", "--victim", cluster.actor("box2"),
        "--server-key", str(certs / "curve" / "replay.key")], timeout=180))
    print(f"\nintruder: {report}")
    assert report["no_certificate"] == "refused" and report["stranger_authority"] == "refused"
    assert report["stolen_certificate"]["opened"]  # the stolen certificate is good: the access rules must hold
    assert report["stolen_certificate"]["acks_heard"] == 0  # box2's acknowledgements do not reach it
    assert report["batch_without_key"] == report["batch_with_stranger_key"] == "nothing"
    time.sleep(2.0)  # a forged message that got through would have reached its receiver by now
    after = cluster.status()
    replay_before, replay_after = before["replay"]["counters"], after["replay"]["counters"]
    # the two batch requests failed their handshake at the replay, which counted them
    assert replay_after.get("zmq_rejected", 0) > replay_before.get("zmq_rejected", 0)
    # forged bytes reaching a receiver would be refused and counted there: none did
    assert replay_after.get("rejected", 0) == replay_before.get("rejected", 0)
    assert after["dashboard"]["counters"]["rejected_messages"] == before["dashboard"]["counters"]["rejected_messages"]
    for box in BOXES:
        actor_before, actor_after = before[cluster.actor(box)]["counters"], after[cluster.actor(box)]["counters"]
        assert {k: actor_after[k] for k in forgery_counters} == {k: actor_before[k] for k in forgery_counters}
    assert after["learner"]["pid"] == before["learner"]["pid"]  # the learner's row is the learner's own


def test_a_host_that_vanishes_is_shown_gone_and_the_run_carries_on(cluster: Cluster):
    box1, box2 = (cluster.actor(box) for box in BOXES)
    before = cluster.status()
    cluster.faults.vanish("box2")  # its actor and its delay proxy die with it; its link is deleted
    cluster.vanished.add("box2")
    vanished_at = time.monotonic()
    gone_after = wait_for(lambda: not cluster.status().get(box2, {}).get("alive", True)
                          and time.monotonic() - vanished_at, 60, "box2 shown gone on the dashboard", interval=0.5)
    carried_on = wait_for(
        lambda: (s := cluster.status()) and s[box1]["counters"]["acked"] >= before[box1]["counters"]["acked"] + 2
        and s["learner"]["counters"]["updates"] > before["learner"]["counters"]["updates"] and s,
        300, "box1's episodes stored and learner updates after box2 vanished", interval=1.0)
    stored = carried_on[box1]["counters"]["acked"] - before[box1]["counters"]["acked"]
    updates = carried_on["learner"]["counters"]["updates"] - before["learner"]["counters"]["updates"]
    print(f"\nbox2 vanished: shown gone after {gone_after:.1f} s (the dashboard's gone_after_s is 3 s); since then "
          f"box1 stored {stored:.0f} episodes and the learner made {updates:.0f} updates")
    assert carried_on[box2]["state"] == "gone" and carried_on[box2]["losses"] >= 1


def test_every_host_stops_cleanly_and_the_replay_holds_every_acknowledged_episode(cluster: Cluster):
    topology = cluster.topology
    present = [box for box in BOXES if box not in cluster.vanished]
    # actors first, as an operator would: their last episodes are acked by the still-running hub
    for name in (*present, "learner"):
        code = topology.stop(cluster.launchers[name], timeout=30)
        assert code == 0, f"{name}'s launcher exited with {code}\n{cluster.launchers[name].output()[-3000:]}"
    topology.stop(cluster.launchers["box2-proxy"], timeout=10)
    for name in (*BOXES, "learner"):
        assert not topology.pids(name), f"{name} left processes behind: {describe(topology.pids(name))}"
    final = cluster.status()
    acked = {box: final[cluster.actor(box)]["counters"]["acked"] for box in BOXES}
    assert all(final[cluster.actor(box)]["state"] == "gone" for box in BOXES)
    code = topology.stop(cluster.launchers["hub"], timeout=30)
    assert code == 0, f"the hub's launcher exited with {code}\n{cluster.launchers['hub'].output()[-3000:]}"
    assert not topology.pids("hub"), f"the hub left processes behind: {describe(topology.pids('hub'))}"

    # the replay checkpointed on stop: what it stored, per actor
    _, snapshot = load_latest(cluster.root / "hub" / "runs" / RUN_ID / "replay" / "checkpoints")
    for box in BOXES:
        ids = sorted(entry[0] for entry in snapshot.dedup.get(cluster.actor(box), []))
        print(f"{box}: told {acked[box]:.0f} episodes stored; the replay holds {len(ids)} from it")
        assert len(ids) >= acked[box]  # no acknowledged episode was lost
        assert ids == list(range(ids[0], ids[0] + len(ids))), f"{box}: episodes missing between {ids[0]}..{ids[-1]}"
