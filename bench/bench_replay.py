"""Replay server benchmarks; prints a markdown table.

    .venv/bin/python bench/bench_replay.py [--quick]

1. ingest over Zenoh from 1/2/4 actor processes, 1 and 4 cameras (128x128, 10 steps,
   float16 points), write-ahead log with fsync on (acks are durable);
2. samples/s with PER at B = 16 and 128 (in-process store, and over ZeroMQ);
3. batch latency seen by a learner (prefetch 1 vs 4, learner busy 50 ms per step);
4. checkpoint and restore MB/s, and the longest ingest pause during checkpoints;
5. resident memory per stored transition;
6. compression none / lz4 / zstd: bytes per transition, insert and sample cost.
"""
from __future__ import annotations

import argparse
import gc
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from synthetic_episodes import synthetic_episode  # noqa: E402  (bench/synthetic_episodes.py)

from deploy.config import cpu  # noqa: E402
from protocol import keys  # noqa: E402
from protocol.fabric import FabricConfig, open_session  # noqa: E402
from protocol.messages import Status, decode, encode  # noqa: E402
from protocol.observation import CAMERA_NAMES  # noqa: E402
from protocol.sample_wire import ReplayClient  # noqa: E402
from replay_server.checkpoint_files import load_checkpoint, write_checkpoint  # noqa: E402
from replay_server.config import ReplayConfig  # noqa: E402
from replay_server.storage import EpisodeStore  # noqa: E402

ROWS: list[tuple[str, str, str]] = []


def row(what: str, value: str, note: str = "") -> None:
    ROWS.append((what, value, note))
    print(f"  {what}: {value} {note}", flush=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, tmp: Path, run_id: str, *settings: str):
        self.run_id = run_id
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.zmq = f"tcp://127.0.0.1:{free_port()}"
        self.router = open_session(FabricConfig(listen=[self.endpoint]), "router")
        self.status: Status | None = None
        self.ack_times: list[float] = []
        self._subs = [
            self.router.declare_subscriber(keys.status(run_id, "replay", "*"), self._on_status),
            self.router.declare_subscriber(keys.acks(run_id, "*"), self._on_ack),
        ]
        cmd = [sys.executable, "-m", "replay_server", "--run-id", run_id, "--run-dir", str(tmp),
               "--connect", self.endpoint, "--zmq-endpoint", self.zmq, "--log-level", "WARNING",
               "--set", "status_interval_s=0.25", "--set", "min_size_to_sample=1"]
        for s in settings:
            cmd += ["--set", s]
        self.proc = subprocess.Popen(cmd, cwd=ROOT)
        self.ps = psutil.Process(self.proc.pid)
        self.wait(lambda c: True)

    def _on_status(self, sample) -> None:
        self.status = decode(sample.payload.to_bytes(), expect=Status)

    def _on_ack(self, sample) -> None:
        self.ack_times.append(time.perf_counter())

    def wait(self, pred, timeout=300.0) -> dict:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            st = self.status
            if st is not None and pred(st.counters):
                return st.counters
            time.sleep(0.05)
        raise TimeoutError(f"replay status never matched; last {self.status}")

    def actors(self, n: int, episodes: int, cameras: int, tag: str) -> float:
        """Run n actor processes; returns episodes/s between the first and the last ack."""
        self.ack_times.clear()
        procs = []
        with tempfile.TemporaryDirectory() as d:
            for i in range(n):
                cmd = [sys.executable, str(ROOT / "bench" / "fake_actor.py"), "--connect", self.endpoint,
                       "--run-id", self.run_id, "--actor-id", f"{tag}-{i}", "--episodes", str(episodes),
                       "--size", "128", "--cameras", str(cameras), "--template", "--outbox", "8",
                       "--ack-timeout", "30", "--deadline", "600", "--out", f"{d}/{i}.json"]
                procs.append(subprocess.Popen(cmd, cwd=ROOT))
            for p in procs:
                if p.wait(900) != 0:
                    raise RuntimeError("bench actor failed")
        t = sorted(self.ack_times)
        return (len(t) - 1) / (t[-1] - t[0])

    def close(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(300)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        for s in self._subs:
            s.undeclare()
        self.router.close()


def episode_mb(cameras: int) -> float:
    ep = synthetic_episode("x", 0, size=128, cameras=tuple(CAMERA_NAMES[:cameras]))
    return len(encode(ep)) / 1e6


def bench_ingest_and_service(tmp: Path, quick: bool) -> None:
    print("ingest over Zenoh (WAL + fsync on, acks durable)")
    for cams, per_actor in ((1, 60 if quick else 150), (4, 15 if quick else 40)):
        mb = episode_mb(cams)
        server = Server(tmp / f"ingest{cams}", f"bench{cams}", "checkpoint_interval_s=0", "checkpoint_on_stop=false",
                        "capacity_transitions=20000")
        rss0 = server.ps.memory_info().rss
        try:
            for n in (1, 2, 4):
                eps = per_actor // n if cams == 4 else per_actor
                rate = server.actors(n, eps, cams, f"c{cams}n{n}")
                row(f"ingest {n} actor(s), {cams} camera(s)", f"{rate:.1f} episodes/s, {rate * mb:.0f} MB/s",
                    f"({mb:.2f} MB/episode, {rate * 10:.0f} transitions/s)")
            c = server.wait(lambda c: c["ingest_queue"] == 0)
            gc.collect()
            rss = server.ps.memory_info().rss
            row(f"resident memory per stored transition, {cams} camera(s)",
                f"{(rss - rss0) / c['size_transitions'] / 1024:.0f} KiB",
                f"(RSS {rss / 2**20:.0f} MiB for {int(c['size_transitions'])} transitions; "
                f"stored bytes {c['bytes'] / c['size_transitions'] / 1024:.0f} KiB/transition)")
            if cams == 1:
                bench_zmq(server, quick)
        finally:
            server.close()
    # checkpoint pauses under load: checkpoints every 1 s while two actors push 1-camera episodes
    server = Server(tmp / "ckpt", "benchckpt", "checkpoint_interval_s=1", "capacity_transitions=4000")
    try:
        rate = server.actors(2, 40 if quick else 100, 1, "ck")
        c = server.wait(lambda c: c["checkpoints"] >= 2)
        row("ingest 2 actors, 1 camera, checkpoint every 1 s", f"{rate:.1f} episodes/s",
            f"({int(c['checkpoints'])} checkpoints, last {c['last_checkpoint_bytes'] / 1e6:.0f} MB in "
            f"{c['last_checkpoint_seconds']:.2f} s)")
        row("longest ingest pause for a checkpoint (snapshot + WAL rotate)", f"{c['checkpoint_max_pause_ms']:.1f} ms")
    finally:
        server.close()


def bench_zmq(server: Server, quick: bool) -> None:
    print("sample service over ZeroMQ (1 camera, PER)")
    for b in (16, 128):
        with ReplayClient(server.zmq, batch_size=b, prefetch=4) as client:
            client.sample(30)
            n = 0
            t0 = time.perf_counter()
            while time.perf_counter() - t0 < (2 if quick else 5):
                batch = client.sample(30)
                client.update_priorities(batch.arrays["indices"], batch.arrays["keys"],
                                         np.random.random(b).astype(np.float32))
                n += 1
            dt = time.perf_counter() - t0
            mb = sum(a.nbytes for a in batch.arrays.values()) / 1e6
            row(f"ZeroMQ samples/s, B={b}, prefetch 4, with priority updates", f"{n * b / dt:.0f} transitions/s",
                f"({n / dt:.1f} batches/s, {mb:.1f} MB/batch)")
    for prefetch, work in ((1, 0.0), (1, 0.05), (4, 0.05)):
        with ReplayClient(server.zmq, batch_size=128, prefetch=prefetch) as client:
            client.sample(30)
            lat = []
            for _ in range(15 if quick else 40):
                if work:
                    time.sleep(work)  # the learner's update step
                t = time.perf_counter()
                client.sample(30)
                lat.append(time.perf_counter() - t)
            lat = np.array(lat) * 1e3
            row(f"learner wait per batch, B=128, prefetch {prefetch}, learner step {work * 1e3:.0f} ms",
                f"p50 {np.percentile(lat, 50):.1f} ms, p99 {np.percentile(lat, 99):.1f} ms")


def bench_in_process(tmp: Path, quick: bool) -> None:
    print("in-process store: compression, sampling, checkpoints")
    n_eps = 100 if quick else 250
    template = synthetic_episode("x", 0, size=128)
    for comp in ("none", "lz4", "zstd"):
        cfg = ReplayConfig(capacity_transitions=n_eps * 10, capacity_bytes=1 << 40, compression=comp)
        store = EpisodeStore(cfg)
        t0 = time.perf_counter()
        for i in range(n_eps):
            template.episode_id = i
            store.insert(template)
        t_ins = time.perf_counter() - t0
        per = store.bytes / store.size / 1024
        rng = np.random.default_rng(0)
        rates = {}
        for b in (16, 128):
            t0 = time.perf_counter()
            k = 0
            while time.perf_counter() - t0 < 1.5:
                s, keys_, p, w, eps, ts = store.sample(b, rng, 0.5)
                store.gather(eps, ts)
                store.update_priorities(s, keys_, rng.random(b))
                k += 1
            rates[b] = k * b / (time.perf_counter() - t0)
        row(f"store, compression={comp}", f"{per:.0f} KiB/transition",
            f"(insert {n_eps / t_ins:.0f} episodes/s; sample+gather+update {rates[16]:.0f} /s at B=16, "
            f"{rates[128]:.0f} /s at B=128, transitions)")
        if comp in ("none", "zstd"):
            d = tmp / f"ck-{comp}"
            t0 = time.perf_counter()
            snap = store.snapshot()
            pause = time.perf_counter() - t0
            res = write_checkpoint(d, snap)
            del snap
            t0 = time.perf_counter()
            loaded = load_checkpoint(res.path)
            restored = EpisodeStore(cfg)
            restored.restore(loaded)
            t_load = time.perf_counter() - t0
            assert np.array_equal(restored.priorities.tree.leaves(), store.priorities.tree.leaves())
            row(f"checkpoint write / restore (verified), compression={comp}",
                f"{res.bytes / 1e6 / res.seconds:.0f} / {res.bytes / 1e6 / t_load:.0f} MB/s",
                f"({res.bytes / 1e6:.0f} MB incl. fsync and CRC; snapshot under lock {pause * 1e3:.1f} ms)")
            del loaded, restored
        del store
        gc.collect()


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--quick", action="store_true")
    a = p.parse_args()
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as d:
        tmp = Path(d)
        bench_in_process(tmp, a.quick)
        bench_ingest_and_service(tmp, a.quick)
    print(f"\n{cpu()}, Python {sys.version.split()[0]}\n")
    print("| measurement | result | notes |\n|---|---|---|")
    for what, value, note in ROWS:
        print(f"| {what} | {value} | {note} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
