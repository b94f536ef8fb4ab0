"""The fabric across machines: episodes and weights over a veth link, plain TCP vs TLS, with loss and delay.

    sudo python bench/bench_multihost.py [--episodes 40] [--weights 20]

One hub namespace runs the router and the replay (`c2farm router` / `c2farm replay`, as on a
real hub) and one actor host, joined by a veth pair into a bridge (``harness``). Per variant,
side by side in one run:

- **episodes actor -> replay**: ``bench/fake_actor.py`` on the actor host puts ``--episodes``
  synthetic episodes of the cpu-small shape (one 128 px RGB-D camera, ``--steps`` observations)
  with its bounded outbox and resends, until each is acknowledged; episodes/s and MB/s from the
  first put to the last ack. The replay is then stopped and its checkpoint read: acknowledged
  episodes it does not hold are **lost** (must be 0);
- **weights hub -> actor host**: a publisher on the hub (the learner's certificate) puts
  ``--weights`` payloads of ``--weights-mb`` MB, one every 0.5 s, stamped with the send time; a
  subscriber on the actor host (an actor's certificate) records arrival - send (one clock:
  the namespaces share the machine's).

Variants: plain TCP (``--insecure``), TLS with mutual authentication and access control
(``--certs``), TLS with 5 % of the hub's incoming packets from the host dropped (nftables), TLS
through a proxy that delays each direction by 100 ms (the kernel here has no netem). Needs
root (network namespaces); run it with nothing else on the machine.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import struct
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

RUN = "bench"
PORT, PROXY_PORT = 7447, 17447


def c2farm(*args: str) -> list[str]:
    return [sys.executable, "-m", "deploy.cli", *args]


def trust(certs: Path | None) -> list[str]:
    return ["--certs", str(certs)] if certs else ["--insecure"]


def variant(topology, faults, root: Path, name: str, certs: Path | None, fault: tuple | None, args) -> dict:
    from replay_server.checkpoint_files import load_latest

    hub, box = topology.hub, "box1"
    work = root / name.replace(" ", "-").replace(",", "").replace("%", "pc")
    router = topology.spawn("hub", c2farm("router", "--run-id", RUN, "--runs-dir", str(work / "runs"), "--listen",
                                          f"tcp/{hub.ip}:{PORT}", *trust(certs)), f"{work.name}-router", cwd=ROOT)
    topology.wait_listening("hub", hub.ip, PORT, timeout=60, process=router)
    replay = topology.spawn("hub", c2farm("replay", "--run-id", RUN, "--runs-dir", str(work / "runs"), "--connect",
                                          f"tcp/{hub.ip}:{PORT}", "--set", "replay.zmq_endpoint=tcp://127.0.0.1:5560",
                                          *trust(certs)), f"{work.name}-replay", cwd=ROOT)
    deadline = time.monotonic() + 120
    while "serving" not in replay.output():
        if not replay.running or time.monotonic() > deadline:
            raise RuntimeError(f"the replay did not start:\n{replay.output()[-2000:]}")
        time.sleep(0.2)
    target = f"{hub.ip}:{PORT}"
    if fault and fault[0] == "loss":
        faults.loss(box, fault[1])
    if fault and fault[0] == "delay":
        proxy = topology.spawn(box, [sys.executable, "-m", "harness.delay_proxy", "--listen",
                                     f"127.0.0.1:{PROXY_PORT}", "--target", target, "--delay-ms", str(fault[1])],
                               f"{work.name}-proxy", cwd=ROOT)
        topology.wait_listening(box, "127.0.0.1", PROXY_PORT, timeout=30, process=proxy)
        target = f"127.0.0.1:{PROXY_PORT}"
    keys = ["--certs", str(certs)] if certs else ["--insecure"]
    latencies = work / "weights.json"
    sub = topology.spawn(box, [sys.executable, __file__, "weights-sub", "--connect", f"tcp/{target}",
                               "--count", str(args.weights), "--out", str(latencies), *keys], f"{work.name}-wsub",
                         cwd=ROOT)
    time.sleep(3)  # the subscriber is declared before the first weights go out
    pub = topology.spawn("hub", [sys.executable, __file__, "weights-pub", "--connect", f"tcp/{hub.ip}:{PORT}",
                                 "--count", str(args.weights), "--mb", str(args.weights_mb), *keys],
                         f"{work.name}-wpub", cwd=ROOT)
    out = work / "actor.json"
    topology.run(box, [sys.executable, str(ROOT / "bench" / "fake_actor.py"), "--connect", f"tcp/{target}",
                       "--run-id", RUN, "--actor-id", "box1-actor-0", "--episodes", str(args.episodes),
                       "--steps", str(args.steps), "--size", "128", "--template", "--source-info",
                       "--ack-timeout", "3", "--deadline", "240", "--out", str(out), *keys], timeout=300)
    actor = json.loads(out.read_text())
    pub.popen.wait(timeout=120)  # it puts every weights payload, then exits
    sub.popen.wait(timeout=120)
    weights = json.loads(latencies.read_text()) if latencies.exists() else []
    faults.clear(box)
    topology.stop(replay, timeout=60)  # it checkpoints on the way out
    topology.stop(router)
    stored = {int(e) for e in _stored_episode_ids(load_latest, work / "runs" / RUN / "replay" / "checkpoints")}
    acked = {int(e) for e in actor["acks"]}
    seconds = actor["seconds"]
    return {"variant": name, "episodes": len(acked), "seconds": seconds, "bytes": actor["bytes"],
            "sends": actor["sends"], "lost": len(acked - stored), "weights": weights}


def _stored_episode_ids(load_latest, directory: Path) -> list[int]:
    """Episode ids of box1 in the replay's newest checkpoint."""
    loaded = load_latest(directory)
    if not loaded:
        return []
    _, snapshot = loaded
    return [int(entry[0]) for entry in snapshot.dedup.get("box1-actor-0", [])]


def weights_pub(argv: list[str]) -> int:
    a = _probe_args(argv, "--mb")
    from protocol import keys
    from protocol.fabric import FabricConfig, open_session

    session = open_session(FabricConfig(connect=[a.connect], certs=a.certs, insecure=a.insecure,
                                        identity="learner.learner"))
    publisher = session.declare_publisher(keys.weights(RUN))
    body = bytes(int(a.mb * 1e6))
    time.sleep(1.0)  # learns of the subscriber (write-side filtering)
    for _ in range(a.count):
        publisher.put(struct.pack("<d", time.time()) + body)
        time.sleep(0.5)
    time.sleep(2.0)
    session.close()
    return 0


def weights_sub(argv: list[str]) -> int:
    a = _probe_args(argv, "--out")
    from protocol import keys
    from protocol.fabric import FabricConfig, open_session

    session = open_session(FabricConfig(connect=[a.connect], certs=a.certs, insecure=a.insecure,
                                        identity="actor.box1-actor-0"))
    got: list[float] = []
    session.declare_subscriber(keys.weights(RUN),
                               lambda s: got.append(time.time() - struct.unpack("<d", s.payload.to_bytes()[:8])[0]))
    deadline = time.monotonic() + 90
    while len(got) < a.count and time.monotonic() < deadline:
        time.sleep(0.1)
    Path(a.out).write_text(json.dumps(got))
    session.close()
    return 0


def _probe_args(argv: list[str], extra: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    p.add_argument("--connect", required=True)
    p.add_argument("--count", type=int, required=True)
    p.add_argument("--certs", default="")
    p.add_argument("--insecure", action="store_true")
    p.add_argument(extra, type=float if extra == "--mb" else str, required=True)
    return p.parse_args(argv)


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] in ("weights-pub", "weights-sub"):
        return (weights_pub if sys.argv[1] == "weights-pub" else weights_sub)(sys.argv[2:])
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=40, help="episodes per variant")
    parser.add_argument("--steps", type=int, default=7, help="observations per episode (cpu-small: 6 decisions)")
    parser.add_argument("--weights", type=int, default=20, help="weights broadcasts per variant")
    parser.add_argument("--weights-mb", type=float, default=2.0, help="size of one weights payload, MB")
    args = parser.parse_args()

    from deploy.certs import CertsPlan, make_certs
    from harness import Faults, Topology, probe

    why = probe()
    if why:
        print(f"bench_multihost: cannot run here: {why}")
        return 2
    root = Path(tempfile.mkdtemp(prefix="bench-multihost-"))
    rows = []
    with Topology(["box1"], root / "logs") as topology:
        certs = root / "certs"
        make_certs(CertsPlan(certs, hubs=[topology.hub.ip], actors=0,
                             extra=["actor.box1-actor-0", "learner.learner"]))
        faults = Faults(topology)
        for name, keyed, fault in (("plain TCP", False, None), ("TLS", True, None),
                                   ("TLS, 5 % loss", True, ("loss", 5)), ("TLS, 100 ms delay", True, ("delay", 100))):
            rows.append(variant(topology, faults, root, name, certs if keyed else None, fault, args))
            print(f"{name}: done", flush=True)
    from deploy.config import cpu

    print(f"\n{cpu()}, Python {platform.python_version()}; {args.episodes} episodes of "
          f"{rows[0]['bytes'] / 1e6:.2f} MB, {args.weights} weights of {args.weights_mb:g} MB per variant; "
          f"files in {root}\n")
    print("| link | episodes/s | MB/s | puts per episode | acked episodes lost | weights latency median (ms) | "
          "max (ms) | weights received |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        w = r["weights"]
        med = f"{statistics.median(w) * 1e3:.0f}" if w else "-"
        worst = f"{max(w) * 1e3:.0f}" if w else "-"
        rate = r["episodes"] / r["seconds"]
        puts = r["sends"] / max(1, r["episodes"])
        print(f"| {r['variant']} | {rate:.1f} | {rate * r['bytes'] / 1e6:.1f} | {puts:.2f} | {r['lost']} | {med} "
              f"| {worst} | {len(w)}/{args.weights} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
