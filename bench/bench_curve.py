"""CURVE vs plaintext on the learner <-> replay sample link; prints a markdown table.

    nice -n 19 .venv/bin/python bench/bench_curve.py            # ~2 minutes
    nice -n 19 .venv/bin/python bench/bench_curve.py --quick    # shorter runs

The replay's sample service runs in its own process (as deployed) over stored 128 px
episodes; the learner side is :class:`ReplayClient` with the learner's default prefetch (2)
in this process, sending a priority update per batch as the learner does. Two batch shapes:
the cpu-small preset's (B=8, one 128 px camera, 3-step) and the paper's batch size (B=128).
For each link (plaintext, CURVE, CURVE with 2 ZeroMQ I/O threads on both ends) it measures
batches/s and MB/s back to back (the link's ceiling) and the learner's wait inside
``ReplayClient.sample``: back to back, and with a 50 ms learner step between calls (a fast
update; prefetch hides the link when a batch arrives faster than a step), and the CPU time
both processes spent per batch (every thread, libzmq's I/O threads included), which is what
CURVE adds and what stays comparable on a busy machine. Torch is never imported. Wall-clock
numbers need an idle machine: the table prints the load average.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil
import zmq
import zmq.auth

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from synthetic_episodes import synthetic_episode  # noqa: E402  (bench/synthetic_episodes.py)

from deploy.config import cpu  # noqa: E402
from protocol.sample_wire import ReplayClient  # noqa: E402

SHAPES = (("cpu-small, B=8", 8), ("paper batch, B=128", 128))  #: one 128 px camera, as the cpu-small preset
LINKS = (("plaintext", False, 1), ("CURVE", True, 1), ("CURVE, 2 I/O threads", True, 2))
STEP_S = 0.05


def serve(spec: dict) -> int:
    """The replay side: a sample service over ``episodes`` stored episodes until stdin closes."""
    from replay_server.config import ReplayConfig
    from replay_server.sample_service import SampleService
    from replay_server.state import ReplayState

    config = ReplayConfig(zmq_endpoint=spec["endpoint"], min_size_to_sample=1, n_step=3,
                          capacity_transitions=100_000, checkpoint_dir=spec["tmp"], zmq_io_threads=spec["io_threads"],
                          curve_certificate=spec.get("certificate", ""), curve_clients=spec.get("clients", ""))
    state = ReplayState.create(config, seed=0)
    episode = synthetic_episode("bench", 0, size=128)
    for i in range(spec["episodes"]):
        episode.episode_id = i
        state.store.insert(episode)
        state.limiter.inserts += episode.num_steps
    service = SampleService(state)
    service.start()
    print("ready", flush=True)
    sys.stdin.read()
    service.close()
    print(json.dumps({k: v for k, v in state.stats.items() if v}), flush=True)
    return 0


def free_endpoint() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


def make_keys(directory: Path) -> dict[str, str]:
    for name in ("replay", "learner"):
        os.chmod(zmq.auth.create_certificates(directory, name)[1], 0o600)
    (directory / "clients").mkdir()
    shutil.copy(directory / "learner.key", directory / "clients")
    return {"server_certificate": str(directory / "replay.key_secret"), "clients": str(directory / "clients"),
            "client_certificate": str(directory / "learner.key_secret"), "server_key": str(directory / "replay.key")}


def cpu_seconds(server: psutil.Process) -> float:
    """CPU time of both ends so far (every thread: libzmq's I/O threads encrypt and decrypt)."""
    t = server.cpu_times()
    return t.user + t.system + time.process_time()


def measure(client: ReplayClient, server: psutil.Process, batch: int, seconds: float, stepped: int) -> dict:
    """Back to back for ``seconds`` (at least 3 batches), then up to ``stepped`` calls after a learner step."""
    client.sample(120)  # connected, handshaken, prefetch queue filled
    client.sample(120)
    waits, n, nbytes = [], 0, 0
    cpu0, t0 = cpu_seconds(server), time.perf_counter()
    while time.perf_counter() - t0 < seconds or n < 3:
        t = time.perf_counter()
        b = client.sample(120)
        waits.append(time.perf_counter() - t)
        client.update_priorities(b.arrays["indices"], b.arrays["keys"], np.random.random(batch).astype(np.float32))
        n += 1
        nbytes += sum(a.nbytes for a in b.arrays.values())
    dt, cpu = time.perf_counter() - t0, cpu_seconds(server) - cpu0
    stepped_waits = []
    t0 = time.perf_counter()
    while len(stepped_waits) < stepped and (time.perf_counter() - t0 < seconds or len(stepped_waits) < 3):
        time.sleep(STEP_S)  # the learner's update
        t = time.perf_counter()
        client.sample(120)
        stepped_waits.append(time.perf_counter() - t)
    ms = np.array(waits) * 1e3
    return {"batches_s": n / dt, "mb_s": nbytes / dt / 1e6, "mb": nbytes / n / 1e6, "cpu_ms": cpu / n * 1e3,
            "p50": np.percentile(ms, 50), "p99": np.percentile(ms, 99),
            "step_p50": statistics.median(stepped_waits) * 1e3}


def run_link(tmp: Path, keys: dict, curve: bool, io_threads: int, seconds: float, stepped: int) -> list[dict]:
    endpoint = free_endpoint()
    spec = {"endpoint": endpoint, "tmp": str(tmp / "replay"), "io_threads": io_threads, "episodes": 40}
    if curve:
        spec.update(certificate=keys["server_certificate"], clients=keys["clients"])
    server = subprocess.Popen([sys.executable, __file__, "--serve", json.dumps(spec)], cwd=ROOT,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        if server.stdout.readline().strip() != "ready":
            raise RuntimeError("the bench replay did not start")
        out = []
        for _, batch in SHAPES:
            with ReplayClient(endpoint, batch, prefetch=2, io_threads=io_threads,
                              curve_certificate=keys["client_certificate"] if curve else "",
                              curve_server_key=keys["server_key"] if curve else "") as client:
                out.append(measure(client, psutil.Process(server.pid), batch, seconds, stepped))
        server.stdin.close()
        counters = json.loads(server.stdout.readline() or "{}")
        if counters.get("zmq_rejected", 0):
            raise RuntimeError(f"the replay refused something: {counters}")
        return out
    finally:
        if server.poll() is None:
            server.kill()
        server.wait(30)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="2 s per measurement instead of 5")
    p.add_argument("--serve", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.serve:
        return serve(json.loads(a.serve))
    seconds, stepped = (2.0, 10) if a.quick else (5.0, 20)
    load = os.getloadavg()
    results: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory() as d:
        keys = make_keys(Path(d))
        for name, curve, io_threads in LINKS:
            results[name] = run_link(Path(d), keys, curve, io_threads, seconds, stepped)
            for (shape, _), r in zip(SHAPES, results[name]):
                print(f"  {name}, {shape}: {r['batches_s']:.1f} batches/s, {r['mb_s']:.0f} MB/s", flush=True)
    assert "torch" not in sys.modules
    print(f"\n{cpu()}, Python {sys.version.split()[0]}, pyzmq {zmq.__version__} "
          f"(libzmq {zmq.zmq_version()}), torch not loaded; load average {load[0]:.1f} at start, "
          f"{os.getloadavg()[0]:.1f} at the end\n")
    print("| batch | MB/batch | link | batches/s | MB/s | wait p50 | wait p99 | "
          f"wait p50 after a {STEP_S * 1e3:.0f} ms step | CPU ms/batch (both ends) | CPU vs plaintext |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for i, (shape, _) in enumerate(SHAPES):
        base = results[LINKS[0][0]][i]["cpu_ms"]
        for name, _, _ in LINKS:
            r = results[name][i]
            print(f"| {shape} | {r['mb']:.1f} | {name} | {r['batches_s']:.1f} | {r['mb_s']:.0f} | {r['p50']:.1f} ms | "
                  f"{r['p99']:.1f} ms | {r['step_p50']:.1f} ms | {r['cpu_ms']:.1f} | {r['cpu_ms'] / base:.2f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
