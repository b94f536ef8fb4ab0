"""Every process the bench starts: one process group each, output in a log file, all stoppable.

A test that fails half-way must not leave role processes behind: on a 2-core machine they
eat the CPU of whatever runs next, and a namespace with a process in it outlives its name. So
every start goes through one :class:`Registry`, which stops them all on the way out (SIGTERM
to each group, SIGKILL at a deadline). Roles that a launcher starts sit in groups of their
own; :class:`harness.netns.Topology` sweeps those by namespace.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Started:
    """One started process: its label, the host it runs on, the Popen and its log file."""

    name: str
    host: str
    popen: subprocess.Popen
    log: Path

    @property
    def pid(self) -> int:
        return self.popen.pid

    @property
    def running(self) -> bool:
        return self.popen.poll() is None

    def output(self) -> str:
        """Everything it wrote so far (stdout and stderr, merged)."""
        try:
            return self.log.read_text(errors="replace")
        except FileNotFoundError:
            return ""


class Registry:
    """Starts processes in their own process groups and remembers them until they are stopped."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._started: list[Started] = []

    def start(self, argv: Sequence[str], *, name: str, host: str, log_dir: Path,
              env: Mapping[str, str] | None = None, cwd: str | os.PathLike | None = None) -> Started:
        """Start ``argv`` with output appended to ``log_dir/<host>-<name>.log``."""
        log_dir.mkdir(parents=True, exist_ok=True)
        log = log_dir / f"{host}-{name}.log"
        with open(log, "ab") as out:  # the child holds its own copy of the descriptor
            popen = subprocess.Popen(list(argv), stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                     env=dict(env) if env is not None else None, cwd=cwd, start_new_session=True)
        started = Started(name, host, popen, log)
        with self._lock:
            self._started.append(started)
        return started

    def all(self, host: str | None = None) -> list[Started]:
        with self._lock:
            return [s for s in self._started if host is None or s.host == host]

    @staticmethod
    def signal(started: Started, sig: int) -> None:
        """Signal the process group, unless its leader was already reaped (the id may be reused)."""
        if started.popen.poll() is not None:
            return
        try:
            os.killpg(started.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def stop(self, started: Started, timeout: float = 15.0) -> int | None:
        """SIGTERM the group and wait; SIGKILL it after ``timeout``. Returns the exit code."""
        self.signal(started, signal.SIGTERM)
        try:
            return started.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.signal(started, signal.SIGKILL)
            return _wait(started.popen, 5.0)

    def stop_all(self, grace_s: float = 3.0, host: str | None = None) -> None:
        """SIGTERM every running group (of ``host``, or all) at once, SIGKILL what is left after ``grace_s``."""
        running = [s for s in self.all(host) if s.running]
        for started in running:
            self.signal(started, signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        for started in running:
            _wait(started.popen, max(0.0, deadline - time.monotonic()))
        for started in running:
            self.signal(started, signal.SIGKILL)
            _wait(started.popen, 5.0)


def _wait(popen: subprocess.Popen, timeout: float) -> int | None:
    try:
        return popen.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        return None
