"""Shared fixtures: free ports, a real Zenoh router, process hygiene.

Episodes come from the one factory, bench/synthetic_episodes.py (``from synthetic_episodes import
synthetic_episode``: pyproject.toml puts bench/ on the tests' path), which benchmarks share.
"""

from __future__ import annotations

import contextlib
import io
import os

# One intra-op thread, set before anything imports torch: on a 2-core machine that is running
# something else, OpenMP's spinning worker threads made the small learning tests ~9x slower
# (248 s vs 28 s for behaviour cloning, past the 300 s timeout in CI). Role processes the
# tests start choose their own thread counts (torch_threads).
os.environ.setdefault("OMP_NUM_THREADS", "1")

import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Callable

import httpx
import numpy as np
import psutil
import pytest

from protocol.fabric import FabricConfig, open_session

REPO = Path(__file__).resolve().parent.parent

#: `c2farm launch` overrides for a run that trains in seconds: tiny networks and batches.
TINY_TRAINING = [
    "--set", "replay.min_size_to_sample=8",
    "--set", "learner.batch_size=2",
    "--set", "learner.publish_every=2",
    "--set", "learner.checkpoint_every=3",
    "--set", "qattention.kernels=8",
    "--set", "qattention.head_width=16",
]


#: A whole run small enough for a test: reach_target, 1 actor, 64 px images, 2 demos, tiny training.
SMALL_RUN = [
    "--task", "reach_target", "--actors", "1",
    "--set", "sim.image_size=64",
    "--set", "demos.episodes=2",
    *TINY_TRAINING,
    "--set", "actor.eval_episodes=1",
    "--set", "actor.eval_every_versions=3",
    "--set", "actor.record_eval=false",
    "--set", "launch.restart_backoff_s=1",
    "--set", "launch.progress_every_s=5",
]


def _our_python_processes() -> dict[int, psutil.Process]:
    """Every process on this machine running this interpreter (the roles and helpers tests start), but us."""
    found = {}
    for p in psutil.process_iter(["cmdline"]):
        cmdline = p.info["cmdline"] or []
        if p.pid != os.getpid() and cmdline and cmdline[0] == sys.executable:
            found[p.pid] = p
    return found


@pytest.fixture(autouse=True, scope="module")
def no_process_left_behind(request):
    """Fail the module that leaves a process of ours running (and kill it).

    A leaked role keeps a core busy for the rest of the suite: on a 2-core machine the later
    real-time tests (franky-sim's 1 kHz loop, launch timings) then fail far from the cause.
    """
    before = set(_our_python_processes())
    yield
    left = [p for pid, p in _our_python_processes().items() if pid not in before]
    _, running = psutil.wait_procs(left, timeout=10)
    running = survivors(running)
    if running:
        names = []
        for p in running:
            with contextlib.suppress(psutil.Error):
                names.append(f"{p.pid} {' '.join(p.cmdline()[1:6])}")
        kill_all([], running)
        pytest.fail(f"{request.module.__name__} left {len(running)} processes running: {'; '.join(names)}")


def get_free_port() -> int:
    """A TCP port that was free a moment ago (bind port 0 and read what the kernel chose)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def free_port() -> Callable[[], int]:
    return get_free_port


@pytest.fixture(params=[True, False], ids=["shm", "no-shm"])
def shm(request) -> bool:
    return request.param


@pytest.fixture
def router(shm: bool):
    """A real Zenoh router session on a free loopback port; yields the FabricConfig to dial it."""
    endpoint = f"tcp/127.0.0.1:{get_free_port()}"
    fabric = FabricConfig(connect=[endpoint], listen=[endpoint], shared_memory=shm)
    session = open_session(fabric, "router")
    try:
        yield fabric
    finally:
        session.close()


def assert_same_message(a, b) -> None:
    """Field-by-field equality of two protocol messages, arrays compared exactly (dtype too)."""
    assert type(a) is type(b)
    for name in a.__dataclass_fields__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, name
            np.testing.assert_array_equal(x, y, err_msg=name)
        elif isinstance(x, dict) and x and all(isinstance(v, np.ndarray) for v in x.values()):
            assert x.keys() == y.keys(), name
            for k in x:
                assert x[k].dtype == y[k].dtype, f"{name}.{k}"
                np.testing.assert_array_equal(x[k], y[k], err_msg=f"{name}.{k}")
        else:
            assert x == y, name


def wait_for(predicate: Callable[[], object], timeout: float, what: str, interval: float = 0.05):
    """Poll ``predicate`` until it returns something truthy; fail naming ``what`` on timeout."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(interval)


def python_cmd(*args: str) -> list[str]:
    return [sys.executable, *args]


def stop_process_tree(proc: subprocess.Popen, timeout: float = 15.0) -> list[psutil.Process]:
    """SIGTERM a process we started (and, failing that, SIGKILL it and its descendants).

    Returns the descendants it had, so a test can check none of them survived.
    """
    try:
        descendants = psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        descendants = []
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pass
    kill_all([proc.pid] if proc.poll() is None else [], descendants)
    return descendants


class Descendants:
    """Every process ever seen below ``pid`` (call :meth:`scan` while they run), so a test can
    check afterwards that none survived, restarted ones included."""

    def __init__(self, pid: int):
        self.pid = pid
        self.seen: dict[int, psutil.Process] = {}

    def scan(self) -> None:
        try:
            for child in psutil.Process(self.pid).children(recursive=True):
                self.seen.setdefault(child.pid, child)
        except psutil.NoSuchProcess:
            pass

    @property
    def processes(self) -> list[psutil.Process]:
        return list(self.seen.values())


def small_launch(run_id: str, tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, list[str], Descendants, int]:
    """A `c2farm launch` of test_training_e2e's small run on free ports: (launcher, its output lines as they
    come, its descendants, the dashboard's port). Stop it with stop_launcher, and kill_launcher in a finally."""
    ports = {name: get_free_port() for name in ("router", "dashboard", "zmq")}
    launcher = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "launch", "--run-id", run_id, "--runs-dir", str(tmp_path / "runs"),
         "--router-port", str(ports["router"]), "--dashboard-port", str(ports["dashboard"]),
         "--set", f"replay.zmq_endpoint=tcp://127.0.0.1:{ports['zmq']}",
         "--set", f"demos.directory={tmp_path / 'demos'}", *SMALL_RUN, *extra],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(line.rstrip() for line in launcher.stdout), daemon=True).start()
    return launcher, lines, Descendants(launcher.pid), ports["dashboard"]


def stop_launcher(launcher: subprocess.Popen, children: Descendants) -> None:
    """SIGTERM a `c2farm launch` and check it stops cleanly, leaving none of its roles behind."""
    launcher.send_signal(signal.SIGTERM)
    assert launcher.wait(timeout=30) == 0
    assert not survivors(children.processes), f"left behind: {survivors(children.processes)}"


def kill_launcher(launcher: subprocess.Popen, children: Descendants) -> None:
    """Last-resort cleanup of a `c2farm launch` (its own process group) and every role it started."""
    if launcher.poll() is None:
        os.killpg(launcher.pid, signal.SIGKILL)
    kill_all([], children.processes)


def kill_all(pids: list[int], processes: list[psutil.Process]) -> None:
    """Last-resort cleanup: SIGKILL the given processes (only those still running)."""
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    for p in processes:
        try:
            if p.is_running():
                p.kill()
        except psutil.NoSuchProcess:
            pass
    psutil.wait_procs([p for p in processes if _exists(p)], timeout=5)


def _exists(p: psutil.Process) -> bool:
    try:
        return p.is_running()
    except psutil.NoSuchProcess:
        return False


def survivors(processes: list[psutil.Process]) -> list[psutil.Process]:
    """Processes from ``processes`` still running (zombies count as gone)."""
    out = []
    for p in processes:
        try:
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


def status_reader(http, children: "Descendants") -> Callable[[], dict]:
    """``status()`` for launch tests: the dashboard's summary plus every role by instance ({} while it
    does not answer); each call also records the launcher's descendants for cleanup."""

    def status() -> dict:
        try:
            snap = http.get("/api/status").json()
        except (httpx.HTTPError, ValueError):
            return {}
        children.scan()
        return {"summary": snap["summary"], **{r["instance"]: r for r in snap["roles"]}}

    return status


def run_c2farm(*argv: str) -> tuple[int, str, str]:
    """``c2farm ARGV`` in this process: (exit code, stdout, stderr)."""
    from deploy.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()
