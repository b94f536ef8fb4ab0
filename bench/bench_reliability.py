"""How fast a live run notices and repairs a fault, and how long a clean stop takes.

    python bench/bench_reliability.py [--roles router replay dashboard learner actor-0 eval] [--stops 2]

Runs ``c2farm launch`` (small networks, like tests/test_fault_injection.py) and, per role:
SIGKILLs it, then times from the kill to (a) the launcher printing that it exited, (b) the
launcher starting it again, (c) the dashboard showing it gone, (d) the dashboard showing it
alive again with a new pid (for the router: every role alive again). Then SIGSTOPs the
learner (killed after ``launch.liveness_timeout_s`` of silence) and times the same. Finally
stops the launcher with SIGTERM while the learner and actor work, ``--stops`` times (the run
is resumed in between), and reports each stop's duration. Times are the bench's monotonic
clock; launcher lines are timed on arrival, the dashboard polled every 0.1 s.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parent.parent
SMALL = [
    "--task", "reach_target", "--actors", "1",
    "--set", "sim.image_size=64", "--set", "demos.episodes=0",
    "--set", "replay.min_size_to_sample=8", "--set", "learner.batch_size=2",
    "--set", "learner.publish_every=2", "--set", "learner.checkpoint_every=3",
    "--set", "qattention.kernels=8", "--set", "qattention.head_width=16",
    "--set", "actor.resend_after_s=2", "--set", "actor.eval_episodes=1", "--set", "actor.eval_every_versions=3",
    "--set", "actor.record_eval=false", "--set", "launch.progress_every_s=0",
]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class Run:
    def __init__(self, runs_dir: Path, roles: list[str], grace_s: float):
        self.ports = [free_port() for _ in range(3)]
        role_kinds = sorted({"actor" if r.startswith("actor") else r for r in roles})
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "deploy.cli", "launch", "--run-id", "reliability", "--runs-dir", str(runs_dir),
             "--router-port", str(self.ports[0]), "--dashboard-port", str(self.ports[1]),
             "--set", f"replay.zmq_endpoint=tcp://127.0.0.1:{self.ports[2]}",
             "--set", f"launch.roles=[{','.join(role_kinds)}]", "--set", f"launch.liveness_grace_s={grace_s}", *SMALL],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        )
        self.lines: list[tuple[float, str]] = []
        threading.Thread(target=self._read, daemon=True).start()
        self.http = httpx.Client(base_url=f"http://127.0.0.1:{self.ports[1]}", timeout=2)

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append((time.monotonic(), line.rstrip()))

    def rows(self) -> dict:
        try:
            return {r["instance"]: r for r in self.http.get("/api/status").json()["roles"]}
        except (httpx.HTTPError, ValueError, KeyError):
            return {}

    def line_after(self, t0: float, text: str) -> float | None:
        return next((t - t0 for t, line in list(self.lines) if t >= t0 and text in line), None)

    def wait(self, predicate, timeout: float, interval: float = 0.1):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = predicate()
            if value:
                return value
            time.sleep(interval)
        return None

    def stop(self) -> float:
        t0 = time.monotonic()
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(timeout=60)
        self.http.close()
        return time.monotonic() - t0


def all_alive(rows: dict, roles: list[str]) -> bool:
    return all(rows.get(r, {}).get("alive") and rows[r].get("pid") for r in roles)


def fault(run: Run, roles: list[str], name: str, sig: int, timeout: float = 240.0) -> dict:
    before = run.wait(lambda: (r := run.rows()) and all_alive(r, roles) and r, timeout)
    if not before:
        return {"role": name, "error": "not every role alive before the fault"}
    victim = before[name]["pid"]
    t0 = time.monotonic()
    os.kill(victim, sig)
    gone = back = None
    while time.monotonic() - t0 < timeout:
        rows = run.rows()
        now = time.monotonic() - t0
        if rows and gone is None and not rows.get(name, {}).get("alive", True):
            gone = now
        if rows and rows[name]["pid"] != victim and all_alive(rows, roles):
            back = now
            break
        time.sleep(0.1)
    if sig == signal.SIGSTOP:
        try:
            os.kill(victim, signal.SIGKILL)
        except ProcessLookupError:
            pass
    exited = run.line_after(t0, f"{name} exited with code")
    return {
        "role": name,
        "signal": signal.Signals(sig).name,
        "launcher_sees_gone_s": exited,
        "launcher_restarts_s": run.line_after(t0, f"started {name} (pid"),
        "dashboard_sees_gone_s": gone if name != "dashboard" else None,
        "dashboard_sees_back_s": back,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--roles", nargs="+", default=["router", "replay", "dashboard", "learner", "actor-0", "eval"])
    parser.add_argument("--stops", type=int, default=2, help="clean stops to time (the run resumes in between)")
    parser.add_argument(
        "--grace",
        type=float,
        default=20.0,
        help="launch.liveness_grace_s (default shorter than the config's, to keep the bench short)",
    )
    parser.add_argument("--out", default=str(REPO / "bench" / "results" / "reliability.json"))
    args = parser.parse_args()
    results: dict = {"faults": [], "stops": []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.stops):
            run = Run(Path(tmp), args.roles, args.grace)
            try:
                if i == 0:
                    for name in args.roles:
                        results["faults"].append(r := fault(run, args.roles, name, signal.SIGKILL))
                        print(r, flush=True)
                    run.wait(lambda: time.sleep(args.grace) or True, args.grace + 1)  # learner past its grace
                    results["faults"].append(r := fault(run, args.roles, "learner", signal.SIGSTOP))
                    print(r, flush=True)
                # Stop under load: learner and actor busy (the learner's count moved a moment ago).
                first = run.wait(lambda: (r := run.rows()) and all_alive(r, args.roles) and r, 240)
                updates = first["learner"]["counters"].get("updates", 0) if first else 0
                run.wait(lambda: run.rows().get("learner", {}).get("counters", {}).get("updates", 0) > updates, 120)
                seconds = run.stop()
                summary = [line for _, line in run.lines if "all roles stopped in" in line or "did not stop" in line]
                results["stops"].append({"seconds": round(seconds, 2), "launcher": summary})
                print(results["stops"][-1], flush=True)
            finally:
                if run.proc.poll() is None:
                    os.killpg(run.proc.pid, signal.SIGKILL)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(
        "| role | signal | launcher sees it gone | launcher restarts it | dashboard shows gone | dashboard shows back |"
    )
    print("|---|---|---|---|---|---|")

    def fmt(v) -> str:
        return "-" if v is None else f"{v:.1f} s"

    for r in results["faults"]:
        if "error" in r:
            print(f"| {r['role']} | error: {r['error']} |")
            continue
        print(f"| {r['role']} | {r['signal']} | {fmt(r['launcher_sees_gone_s'])} | {fmt(r['launcher_restarts_s'])} "
              f"| {fmt(r['dashboard_sees_gone_s'])} | {fmt(r['dashboard_sees_back_s'])} |")
    print("clean stops under load: " + ", ".join(f"{s['seconds']:.1f} s" for s in results["stops"]))


if __name__ == "__main__":
    main()
