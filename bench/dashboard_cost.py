"""What watching the dashboard costs a training run: learner and actor rates with the page polled vs not.

    python bench/dashboard_cost.py --task push_button --window 120 --rounds 3

Runs ``c2farm launch`` (the whole system, one machine), lets it warm up, then alternates windows
of ``--window`` seconds: *idle* (nobody polls the dashboard) and *polled* (a client polls it
exactly as the page does: ``/api/status`` every second, ``/api/history`` every 3 s,
``/api/episodes`` and ``/api/qattention`` every 10 s, revalidating with the ETag it was given, and
fetching every camera frame of an evaluation it has not seen). The order alternates per round
(idle-polled, polled-idle, ...) so a trend in the run (the replay filling, episodes getting
longer) does not land on one condition. Per window it reads the learner's ``updates`` and the
actors' ``env_steps`` from ``/api/status`` at its two ends (two requests, in both conditions)
and the dashboard process's CPU seconds (psutil), then prints the mean of each condition.

What it does not measure: a browser's own rendering (charts, three.js), which runs wherever
the browser runs; on the training machine itself that is a cost of the browser, not of the
dashboard.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

import httpx
import psutil

#: (path, period in seconds) as dashboard/static/app.js polls them at its default refresh.
PAGE_POLLS = (("api/status", 1.0), ("api/history", 3.0), ("api/episodes", 10.0), ("api/qattention", 10.0))


@dataclass
class Window:
    condition: str  #: "idle" or "polled"
    seconds: float
    updates: float
    env_steps: float
    dashboard_cpu_s: float
    requests: int = 0

    @property
    def updates_per_s(self) -> float:
        return self.updates / self.seconds

    @property
    def env_steps_per_s(self) -> float:
        return self.env_steps / self.seconds


class PagePoller:
    """A client that polls the dashboard as the page does, until stopped."""

    def __init__(self, base: str):
        self.base, self.requests = base.rstrip("/") + "/", 0
        self._stop = threading.Event()
        self._etags: dict[str, str] = {}
        self._seen_frames: set[str] = set()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self.requests = 0
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def stop(self) -> int:
        self._stop.set()
        if self._thread:
            self._thread.join(10)
        return self.requests

    def _run(self) -> None:
        due = {path: 0.0 for path, _ in PAGE_POLLS}
        with httpx.Client(timeout=10.0) as client:
            while not self._stop.is_set():
                now = time.monotonic()
                for path, period in PAGE_POLLS:
                    if now >= due[path]:
                        due[path] = now + period
                        self._get(client, path)
                self._stop.wait(0.05)

    def _get(self, client: httpx.Client, path: str) -> None:
        headers = {"If-None-Match": self._etags[path]} if path in self._etags else {}
        try:
            res = client.get(self.base + path, headers=headers)
        except httpx.HTTPError:
            return
        self.requests += 1
        if res.status_code != 200:
            return
        if "ETag" in res.headers:
            self._etags[path] = res.headers["ETag"]
        if path == "api/episodes":  # the page loads every frame of a new evaluation once
            for episode in res.json().get("episodes", []):
                for frame in episode.get("frames", []):
                    for url in frame.get("images", {}).values():
                        key = url.split("?")[0]
                        if key not in self._seen_frames:
                            self._seen_frames.add(key)
                            try:
                                client.get(self.base + url)
                                self.requests += 1
                            except httpx.HTTPError:
                                pass


def totals(base: str) -> tuple[float, float]:
    """(learner updates, env steps of every actor) from /api/status."""
    status = httpx.get(base.rstrip("/") + "/api/status", timeout=10.0).json()
    summary = status.get("summary", {})
    return float(summary.get("updates") or 0.0), float(summary.get("env_steps") or 0.0)


def dashboard_process(launcher: psutil.Process) -> psutil.Process:
    for child in launcher.children(recursive=True):
        try:
            if "dashboard" in child.cmdline():
                return child
        except psutil.Error:
            continue
    raise RuntimeError("no dashboard process under the launcher")


def cpu_seconds(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    return t.user + t.system


def measure(base: str, dashboard: psutil.Process, poller: PagePoller, condition: str, seconds: float) -> Window:
    updates0, steps0 = totals(base)
    cpu0, t0 = cpu_seconds(dashboard), time.monotonic()
    if condition == "polled":
        poller.start()
    time.sleep(seconds)
    requests = poller.stop() if condition == "polled" else 0
    updates1, steps1 = totals(base)
    elapsed = time.monotonic() - t0
    return Window(condition, elapsed, updates1 - updates0, steps1 - steps0, cpu_seconds(dashboard) - cpu0, requests)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="push_button")
    parser.add_argument("--preset", default="cpu-small")
    parser.add_argument("--window", type=float, default=120.0, help="seconds per window")
    parser.add_argument("--rounds", type=int, default=3, help="idle+polled pairs")
    parser.add_argument(
        "--warmup", type=float, default=180.0, help="seconds before the first window (demos, first updates)"
    )
    parser.add_argument("--dashboard", default="http://127.0.0.1:8080/")
    parser.add_argument("--run-id", default=f"dashcost-{int(time.time())}")
    parser.add_argument("--set", action="append", default=[], help="extra launch settings (key=value)")
    args = parser.parse_args()

    cmd = [sys.executable, "-m", "deploy.cli", "launch", "--preset", args.preset, "--task", args.task,
           "--run-id", args.run_id]
    for item in args.set:
        cmd += ["--set", item]
    print("+ " + " ".join(cmd), flush=True)
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    windows: list[Window] = []
    try:
        time.sleep(args.warmup)
        dashboard = dashboard_process(psutil.Process(proc.pid))
        poller = PagePoller(args.dashboard)
        for r in range(args.rounds):
            order = ("idle", "polled") if r % 2 == 0 else ("polled", "idle")
            for condition in order:
                w = measure(args.dashboard, dashboard, poller, condition, args.window)
                windows.append(w)
                print(
                    f"round {r + 1} {condition:6s}: {w.updates_per_s:.3f} updates/s, "
                    f"{w.env_steps_per_s:.3f} env steps/s, "
                    f"dashboard {100 * w.dashboard_cpu_s / w.seconds:.1f} % CPU, {w.requests} requests",
                    flush=True,
                )
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)

    print("\n| condition | windows | learner updates/s | env steps/s | dashboard CPU | requests/s |")
    print("|---|---|---|---|---|---|")
    for condition in ("idle", "polled"):
        ws = [w for w in windows if w.condition == condition]
        if not ws:
            continue
        mean = lambda f: statistics.mean(f(w) for w in ws)  # noqa: E731
        print(
            f"| {condition} | {len(ws)} | {mean(lambda w: w.updates_per_s):.3f} "
            f"| {mean(lambda w: w.env_steps_per_s):.3f} "
            f"| {100 * mean(lambda w: w.dashboard_cpu_s / w.seconds):.1f} % "
            f"| {mean(lambda w: w.requests / w.seconds):.2f} |"
        )


if __name__ == "__main__":
    main()
