"""Does a run keep learning over a lossy or a delayed link, and at what cost?

    sudo python bench/bench_multihost_training.py [--variants clean,loss5,delay100] [--window-s 180] [--json PATH]

Per variant, a fresh secure run (TLS with mutual authentication, keys from ``deploy.certs``)
across two network namespaces on a bridge (``harness``), shaped like tests/test_multihost.py:

- hub: ``c2farm launch --listen ... --actors 0`` with the router, replay, dashboard, learner and
  demo source (no evaluator: the CPU is the actor's and the learner's);
- box1: ``c2farm launch --roles actor --actors 1 --connect ...``, its own runs directory and
  /dev/shm, so every episode and every weights update crosses the veth.

Links: ``clean``; ``lossN``: N % of box1's packets dropped each way (nftables on the hub's side),
from box1's first acknowledged episode on; ``delayN``: box1 dials a ``harness.delay_proxy`` on its
own 127.0.0.1 that adds N ms each way. Once the learner has updated and box1 has an episode
acknowledged, the hub dashboard's /api/status is sampled for ``--window-s`` seconds: learner
updates/s, box1 env steps/s and acknowledged episodes/s, weights staleness at box1, outbox
resends, bytes box1 sent per acknowledged episode, and the learner's loss (sum over the cascade's
depths) near the start and the end of the window. Every launcher is then stopped (exit codes
reported) and the namespaces deleted. Needs root; run it with nothing else on the machine.
"""

from __future__ import annotations

import argparse
import http.client
import json
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RUN = "bench-training"
BOX, ACTOR = "box1", "box1-actor-0"
ROUTER_PORT, ZMQ_PORT, DASHBOARD_PORT, PROXY_PORT = 7447, 5560, 8080, 17447

#: tests/conftest.py's TINY_TRAINING (copied: a bench imports nothing from tests/), batch size apart
TINY_TRAINING = [
    "--set", "replay.min_size_to_sample=8",
    "--set", "learner.publish_every=2",
    "--set", "learner.checkpoint_every=3",
    "--set", "qattention.kernels=8",
    "--set", "qattention.head_width=16",
]

#: tests/test_multihost.py's SMALL, less its evaluation and quick-resend settings: the hub runs no
#: evaluator, and resends should happen when the deployed default says so
SMALL = [
    "--task", "reach_target",
    "--set", "sim.image_size=64",
    "--set", "demos.episodes=2",
    *TINY_TRAINING,
    "--set", "launch.restart_backoff_s=1",
    "--set", "launch.progress_every_s=0",
    "--set", "launch.router_wait_s=120",  # a starved machine can take more than the default 20 s
]


def c2farm(*args: str) -> list[str]:
    return [sys.executable, "-m", "deploy.cli", *args]


def settings(args: argparse.Namespace) -> list[str]:
    """What every host passes: the networks must agree, or weights would not fit the actor's."""
    return [*SMALL, "--set", f"learner.batch_size={args.batch_size}"]


def hub_command(hub_ip: str, work: Path, args: argparse.Namespace) -> list[str]:
    return c2farm(
        "launch", "--run-id", RUN, "--runs-dir", str(work / "hub" / "runs"),
        "--listen", f"tcp/{hub_ip}:{ROUTER_PORT}", "--actors", "0",
        "--roles", "router,replay,dashboard,learner,demo_source", "--dashboard-port", str(DASHBOARD_PORT),
        "--set", f"replay.zmq_endpoint=tcp://0.0.0.0:{ZMQ_PORT}",
        "--set", f"demos.directory={work / 'hub' / 'demos'}", "--certs", str(work / "certs"), *settings(args),
    )


def actor_command(router: str, work: Path, args: argparse.Namespace) -> list[str]:
    """``router``: the HOST:PORT box1 dials (the hub's, or a delay proxy's in front of it)."""
    return c2farm(
        "launch", "--run-id", RUN, "--runs-dir", str(work / BOX / "runs"), "--roles", "actor", "--actors", "1",
        "--connect", f"tcp/{router}", "--set", f"launch.instance_prefix={BOX}-", "--certs", str(work / "certs"),
        *settings(args),
    )


def parse_variant(name: str) -> tuple[str, int]:
    """``clean`` / ``lossN`` / ``delayN`` as (kind, amount): one spelling in the flag and the table."""
    if name == "clean":
        return "clean", 0
    m = re.fullmatch(r"(loss|delay)(\d+)", name)
    if not m:
        raise argparse.ArgumentTypeError(f"unknown variant {name!r}: expected clean, lossN (%) or delayN (ms)")
    return m[1], int(m[2])


@dataclass
class Sample:
    """One status snapshot in the window: the learner's and box1's counters, and box1's link bytes."""

    t: float
    learner: dict
    actor: dict
    sent_bytes: int


@dataclass
class Run:
    """One variant's bench: its launchers, and the hub dashboard seen from inside the hub."""

    topology: object
    launchers: dict = field(default_factory=dict)

    def status(self) -> dict:
        """/api/status as {instance: counters}; {} while it does not answer (the dashboard binds the hub's loopback)."""
        try:
            with self.topology.inside("hub"):
                conn = http.client.HTTPConnection("127.0.0.1", DASHBOARD_PORT, timeout=5)
                conn.request("GET", "/api/status")
                body = conn.getresponse().read()
                conn.close()
            return {row["instance"]: row.get("counters", {}) for row in json.loads(body)["roles"]}
        except (OSError, ValueError, KeyError, http.client.HTTPException):
            return {}

    def check_alive(self) -> None:
        """Fail at once, with its log, when a launcher died: waiting out a timeout would only hide why."""
        for name, started in self.launchers.items():
            if not started.running:
                raise RuntimeError(f"{name} exited ({started.popen.returncode}):\n{started.output()[-3000:]}")

    def wait_for(self, ready, timeout: float, what: str) -> dict:
        """Poll the status until ``ready(status)``; the status, or TimeoutError naming ``what``."""
        deadline = time.monotonic() + timeout
        while True:
            self.check_alive()
            s = self.status()
            if s and ready(s):
                return s
            if time.monotonic() > deadline:
                raise TimeoutError(f"no {what} after {timeout:.0f} s; last status {s}")
            time.sleep(2.0)


def start(run: Run, work: Path, kind: str, amount: int, args: argparse.Namespace) -> None:
    """The hub's launcher, a delay proxy on box1 for ``delay``, then box1's launcher."""
    topology = run.topology
    hub_ip = topology.hub.ip
    run.launchers["hub"] = topology.spawn("hub", hub_command(hub_ip, work, args), "launch", cwd=ROOT)
    topology.wait_listening("hub", hub_ip, ROUTER_PORT, timeout=args.start_timeout_s, process=run.launchers["hub"])
    router = f"{hub_ip}:{ROUTER_PORT}"
    if kind == "delay":
        proxy = topology.spawn(BOX, [sys.executable, "-m", "harness.delay_proxy", "--listen",
                                     f"127.0.0.1:{PROXY_PORT}", "--target", router, "--delay-ms", str(amount)],
                               "delay-proxy", cwd=ROOT)
        run.launchers["proxy"] = proxy
        topology.wait_listening(BOX, "127.0.0.1", PROXY_PORT, timeout=60, process=proxy)
        router = f"127.0.0.1:{PROXY_PORT}"
    run.launchers[BOX] = topology.spawn(BOX, actor_command(router, work, args), "launch", cwd=ROOT)


def warm_up(run: Run, faults, kind: str, amount: int, args: argparse.Namespace) -> None:
    """Until box1 has an episode acknowledged (then the loss goes on) and the learner has updated."""
    began = time.monotonic()
    s = run.wait_for(lambda s: s.get(ACTOR, {}).get("acked", 0) >= 1, args.start_timeout_s,
                     f"episode acknowledged to {ACTOR}")
    print(f"  {ACTOR}: first episode acknowledged after {time.monotonic() - began:.0f} s", flush=True)
    if "env_steps" not in s[ACTOR]:
        print(f"  {ACTOR} has no env_steps counter; it has: {sorted(s[ACTOR])}", flush=True)
    if kind == "loss":
        faults.loss(BOX, amount)
    left = max(60.0, args.start_timeout_s - (time.monotonic() - began))
    run.wait_for(lambda s: s.get("learner", {}).get("updates", 0) >= 1, left, "learner update")
    print(f"  learner: first updates after {time.monotonic() - began:.0f} s; measuring {args.window_s:.0f} s",
          flush=True)


def measure(run: Run, args: argparse.Namespace) -> list[Sample]:
    """Snapshots every ``--interval-s`` for ``--window-s`` seconds (only those with both rows)."""
    samples: list[Sample] = []
    end = time.monotonic() + args.window_s
    while True:
        run.check_alive()
        s = run.status()
        now = time.monotonic()
        if "learner" in s and ACTOR in s:
            samples.append(Sample(now, s["learner"], s[ACTOR], run.topology.link_counters(BOX)["sent_bytes"]))
        if now >= end:
            break
        time.sleep(min(args.interval_s, max(0.0, end - now)))
    if len(samples) < 2:
        raise RuntimeError(f"fewer than two status snapshots in the {args.window_s:.0f} s window")
    return samples


def stop(run: Run) -> dict[str, int | None]:
    """Stop the launchers as an operator would: box1 first (its last episodes acked by the running hub)."""
    order = [name for name in (BOX, "proxy", "hub") if name in run.launchers]
    return {name: run.topology.stop(run.launchers[name], timeout=30) for name in order}


def loss_of(counters: dict) -> float | None:
    """The learner's loss summed over the cascade's depths (``loss/depthN``); None before it reports one."""
    parts = [v for k, v in counters.items() if k.startswith("loss/")]
    return sum(parts) if parts else None


def mean_loss(samples: list[Sample]) -> float | None:
    """Mean loss over distinct updates: one update's loss on a small batch is too noisy to compare alone."""
    by_update = {s.learner.get("updates"): loss_of(s.learner) for s in samples}
    values = [v for v in by_update.values() if v is not None]
    return statistics.fmean(values) if values else None


def summarise(name: str, samples: list[Sample], exits: dict) -> dict:
    """The table's row from the window's first and last snapshots (losses from its first and last quarter)."""
    a, b = samples[0], samples[-1]
    dt = b.t - a.t

    def rate(row: str, key: str) -> float:
        return (getattr(b, row).get(key, 0) - getattr(a, row).get(key, 0)) / dt

    staleness = [s.learner.get("weights_version", 0) - s.actor.get("weights_version", 0) for s in samples]
    acked = b.actor.get("acked", 0) - a.actor.get("acked", 0)
    quarter = max(1, len(samples) // 4)
    return {
        "variant": name, "seconds": dt,
        "updates_per_s": rate("learner", "updates"), "env_steps_per_s": rate("actor", "env_steps"),
        "acked_per_s": rate("actor", "acked"),
        "learner_version": b.learner.get("weights_version", 0), "box1_version": b.actor.get("weights_version", 0),
        "staleness_mean": statistics.fmean(staleness), "staleness_max": max(staleness),
        "resends": b.actor.get("resent", 0) - a.actor.get("resent", 0),
        "kb_per_acked": (b.sent_bytes - a.sent_bytes) / 1e3 / acked if acked else None,
        "loss_start": mean_loss(samples[:quarter]), "loss_end": mean_loss(samples[-quarter:]),
        "exit_codes": exits,
    }


def run_variant(name: str, root: Path, args: argparse.Namespace) -> dict:
    """One fresh run on a fresh bench; the Topology deletes every namespace and process, pass or fail."""
    from deploy.certs import CertsPlan, make_certs
    from harness import Faults, Topology

    kind, amount = parse_variant(name)
    work = root / name
    with Topology([BOX], work / "logs") as topology:
        make_certs(CertsPlan(work / "certs", hubs=[topology.hub.ip], actors=0, extra=[f"actor.{ACTOR}"]))
        run = Run(topology)
        start(run, work, kind, amount, args)
        warm_up(run, Faults(topology), kind, amount, args)
        samples = measure(run, args)
        return summarise(name, samples, stop(run))


def fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def print_table(rows: list[dict], args: argparse.Namespace, root: Path) -> None:
    from deploy.config import cpu

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip() or "?"
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(f"\n{cpu()}, Python {platform.python_version()}; {date}, commit {commit}; "
          f"batch {args.batch_size}, {args.window_s:.0f} s window per variant; files in {root}\n")
    print("| link | learner updates/s | box1 env steps/s | episodes acked/s | weights v learner / box1 | "
          "staleness mean / max | resends | kB sent per acked episode | loss start -> end | clean stop |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['variant']} | failed: {r['error']} |")
            continue
        clean = "yes" if all(code == 0 for code in r["exit_codes"].values()) else f"no {r['exit_codes']}"
        print(f"| {r['variant']} | {r['updates_per_s']:.2f} | {r['env_steps_per_s']:.2f} | {r['acked_per_s']:.3f} | "
              f"{r['learner_version']:.0f} / {r['box1_version']:.0f} | {r['staleness_mean']:.1f} / "
              f"{r['staleness_max']:.0f} | {r['resends']:.0f} | {fmt(r['kb_per_acked'], '.0f')} | "
              f"{fmt(r['loss_start'], '.3g')} -> {fmt(r['loss_end'], '.3g')} | {clean} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", default="clean,loss5,delay100",
                        help="comma-separated links: clean, lossN (%% dropped each way), delayN (ms each way)")
    parser.add_argument("--window-s", type=float, default=180.0, help="measuring window per variant, seconds")
    parser.add_argument("--interval-s", type=float, default=5.0, help="between status snapshots, seconds")
    parser.add_argument("--start-timeout-s", type=float, default=900.0,
                        help="for the first acknowledged episode and the first learner update (torch loads slowly)")
    parser.add_argument("--batch-size", type=int, default=4,
                        help="learner batch (tests use 2; a little more keeps the learner the bottleneck)")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args()
    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    for name in names:
        try:
            parse_variant(name)
        except argparse.ArgumentTypeError as exc:
            parser.error(str(exc))

    from harness import probe

    why = probe()
    if why:
        print(f"bench_multihost_training: cannot run here: {why}")
        return 2
    root = Path(tempfile.mkdtemp(prefix="bench-multihost-training-"))
    rows = []
    for name in names:
        print(f"{name}: starting", flush=True)
        try:
            rows.append(run_variant(name, root, args))
        except (RuntimeError, TimeoutError) as exc:  # the other variants still tell something
            print(f"{name}: failed: {exc}", file=sys.stderr, flush=True)
            rows.append({"variant": name, "error": str(exc).splitlines()[0][:200]})
            continue
        print(f"{name}: done", flush=True)
    print_table(rows, args, root)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 1 if any("error" in r for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())
