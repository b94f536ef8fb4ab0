"""Protocol benchmark: codec speed and episode throughput over Zenoh on loopback.

    .venv/bin/python bench/bench_protocol.py            # prints a markdown table
    .venv/bin/python bench/bench_protocol.py --quick    # fewer repetitions

Episodes are the sizes actors send: 128x128 cameras, 10 steps (11 observations), float16
points, with 1 camera and with all 4. The Zenoh path is the deployed one: a router process,
a publisher client (this process, CongestionControl.BLOCK) and a subscriber client process
that decodes and validates every episode; it runs with Zenoh shared memory on (same-host
default) and off (what crosses a real network).
"""

from __future__ import annotations

import argparse
import json
import platform
import socket
import statistics
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import zenoh

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from synthetic_episodes import synthetic_episode  # noqa: E402  (bench/synthetic_episodes.py, the tests' too)

from deploy import config as deploy_config  # noqa: E402
from protocol import Episode, decode, encode, keys  # noqa: E402
from protocol.fabric import FabricConfig, open_session  # noqa: E402
from protocol.observation import CAMERA_NAMES  # noqa: E402

SIZES = {"1 camera": ("front",), "4 cameras": CAMERA_NAMES}

ROUTER = """
import sys
from protocol.fabric import FabricConfig, open_session
session = open_session(FabricConfig(listen=[sys.argv[1]], shared_memory=sys.argv[2] == "1"), "router")
print("ready", flush=True)
sys.stdin.read()
session.close()
"""

SUBSCRIBER = """
import json, sys, time
from protocol import Episode, decode, keys
from protocol.fabric import FabricConfig, open_session
session = open_session(FabricConfig(connect=[sys.argv[1]], shared_memory=sys.argv[2] == "1"))
expected = int(sys.argv[3])
state = {"n": 0, "bytes": 0, "bad": 0}
def on_episode(sample):
    data = sample.payload.to_bytes()
    try:
        decode(data, expect=Episode)
    except Exception:
        state["bad"] += 1
    state["n"] += 1
    state["bytes"] += len(data)
    if state["n"] == expected:
        state["done"] = time.time()
sub = session.declare_subscriber(keys.episodes("bench", "*"), on_episode)
token = session.liveliness().declare_token("c2farm/bench/ready")
while "done" not in state:
    time.sleep(0.001)
print(json.dumps(state), flush=True)
token.undeclare(); sub.undeclare(); session.close()
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bench_codec(repeats: int) -> list[dict]:
    rows = []
    for name, cameras in SIZES.items():
        episode = synthetic_episode(cameras=cameras, steps=10, size=128)
        data = encode(episode)
        enc = [_timed(lambda: encode(episode)) for _ in range(repeats)]
        dec = [_timed(lambda: decode(data, expect=Episode)) for _ in range(repeats)]
        mb = len(data) / 1e6
        rows.append(
            {
                "episode": name,
                "MB": mb,
                "encode MB/s": mb / statistics.median(enc),
                "decode+validate MB/s": mb / statistics.median(dec),
                "encode ms": 1e3 * statistics.median(enc),
                "decode ms": 1e3 * statistics.median(dec),
            }
        )
    return rows


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def bench_zenoh(shm: bool, count: dict[str, int], warmup: int = 5) -> list[dict]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    flag = "1" if shm else "0"
    env_cwd = dict(cwd=REPO, text=True)
    router = subprocess.Popen([sys.executable, "-c", ROUTER, endpoint, flag], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, **env_cwd)
    rows = []
    try:
        assert router.stdout.readline().strip() == "ready"
        session = open_session(FabricConfig(connect=[endpoint], shared_memory=shm))
        try:
            for name, cameras in SIZES.items():
                n = count[name]
                data = encode(synthetic_episode(cameras=cameras, steps=10, size=128))
                sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, endpoint, flag, str(n + warmup)],
                                       stdout=subprocess.PIPE, **env_cwd)
                try:
                    _wait_ready(session)
                    pub = session.declare_publisher(keys.episodes("bench", "actor-0"),
                                                    congestion_control=zenoh.CongestionControl.BLOCK)
                    for _ in range(warmup):
                        pub.put(data)
                    time.sleep(0.5)  # let the warm-up drain so it does not count
                    start = time.time()
                    for _ in range(n):
                        pub.put(data)
                    result = json.loads(sub.communicate(timeout=300)[0])
                    pub.undeclare()
                finally:
                    if sub.poll() is None:
                        sub.kill()
                        sub.wait()
                seconds = result["done"] - start
                rows.append(
                    {
                        "shm": "on" if shm else "off",
                        "episode": name,
                        "MB": len(data) / 1e6,
                        "episodes": n,
                        "episodes/s": n / seconds,
                        "MB/s": n * len(data) / 1e6 / seconds,
                        "rejected": result["bad"],
                    }
                )
                _wait_gone(session)
        finally:
            session.close()
    finally:
        router.stdin.close()
        router.wait(timeout=10)
    return rows


def _wait_ready(session) -> None:
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if any(r.ok is not None for r in session.liveliness().get("c2farm/bench/ready", timeout=1.0)):
            return
        time.sleep(0.05)
    raise RuntimeError("the subscriber did not come up")


def _wait_gone(session) -> None:
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        if not any(r.ok is not None for r in session.liveliness().get("c2farm/bench/ready", timeout=1.0)):
            return
        time.sleep(0.05)


def table(rows: list[dict], columns: list[str]) -> str:
    def fmt(v):
        return f"{v:,.1f}" if isinstance(v, float) else str(v)

    out = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    out += ["| " + " | ".join(fmt(r[c]) for c in columns) + " |" for r in rows]
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (a smoke run)")
    args = parser.parse_args()
    repeats = 5 if args.quick else 30
    count = {"1 camera": 20, "4 cameras": 10} if args.quick else {"1 camera": 200, "4 cameras": 60}

    cpu = deploy_config.cpu()
    print(f"machine: {cpu}, Python {platform.python_version()}, zenoh {metadata.version('eclipse-zenoh')}, "
          f"numpy {metadata.version('numpy')}, safetensors {metadata.version('safetensors')}\n")
    print("Codec (median of %d):\n" % repeats)
    print(
        table(bench_codec(repeats), ["episode", "MB", "encode MB/s", "decode+validate MB/s", "encode ms", "decode ms"])
    )
    rows = bench_zenoh(True, count) + bench_zenoh(False, count)
    rows.sort(key=lambda r: (r["episode"], r["shm"] == "off"))
    print("\nZenoh loopback, client -> router -> client, subscriber decodes every episode:\n")
    print(table(rows, ["episode", "shm", "MB", "episodes", "episodes/s", "MB/s", "rejected"]))




if __name__ == "__main__":
    main()
