"""How the launcher knows a role is alive, and a role knows its launcher is: both via the OS.

- **Beacon**: a role started by the launcher touches ``runs/<id>/heartbeats/<instance>``
  every second from a thread of its own, from the first moment of the process (before its
  slow imports). The launcher kills (SIGKILL) and restarts a role whose beacon stops: a
  SIGSTOPped process, or one hung in native code holding the GIL. A file rather than the
  Zenoh status: it keeps working while the router is down or restarting, and the launcher
  needs no session. The launcher reads it on its own monotonic clock (when did the mtime last
  change), so a wall-clock jump cannot make every role look silent.
- **Parent**: a role stops when the launcher that started it is gone (its parent pid changes).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path
from typing import Optional

PARENT_ENV = "C2FARM_PARENT_PID"  #: set by the launcher: a role stops when its launcher is gone
BEACON_ENV = "C2FARM_BEACON"  #: set by the launcher: the file a role touches every BEACON_PERIOD_S
BEACON_PERIOD_S = 1.0

log = logging.getLogger("c2farm")


def beacon_path(run_dir: Path, instance: str) -> Path:
    return Path(run_dir) / "heartbeats" / instance


# -- the role's side -----------------------------------------------------------------------


def start_beacon(path: Path, period_s: float = BEACON_PERIOD_S) -> threading.Thread:
    """Touch ``path`` now and every ``period_s`` from a daemon thread (errors never stop it)."""
    path = Path(path)

    def beat() -> None:
        try:
            os.utime(path)
        except FileNotFoundError:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(f"{os.getpid()}\n")

    def loop() -> None:
        while True:
            try:
                beat()
            except OSError:
                pass  # a full or vanished run dir must not take the role down
            time.sleep(period_s)

    thread = threading.Thread(target=loop, name="beacon", daemon=True)
    thread.start()
    return thread


def start_beacon_from_env() -> Optional[threading.Thread]:
    """Start the beacon if this process was started by a launcher (``C2FARM_BEACON`` set)."""
    path = os.environ.get(BEACON_ENV)
    return start_beacon(Path(path)) if path else None


def watch_parent(parent_pid: int, stop: threading.Event) -> None:
    """Set ``stop`` once our parent is no longer ``parent_pid`` (the launcher died)."""

    def loop() -> None:
        while not stop.wait(0.5):
            if os.getppid() != parent_pid:
                log.warning("launcher (pid %d) is gone; stopping", parent_pid)
                stop.set()

    threading.Thread(target=loop, name="watch-parent", daemon=True).start()


# -- the launcher's side -------------------------------------------------------------------


class BeaconWatch:
    """How long a role's beacon has not changed, measured on the launcher's monotonic clock."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.seen = False  #: the current process has beaten at least once
        self._mtime: Optional[int] = None
        self._since = time.monotonic()

    def reset(self) -> None:
        """Forget the previous process's beacon; call just before starting a new one."""
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass
        self.seen, self._mtime, self._since = False, None, time.monotonic()

    def silent_for(self) -> float:
        """Seconds since the beacon last changed (since :meth:`reset` if it never did)."""
        now = time.monotonic()
        try:
            mtime = self.path.stat().st_mtime_ns
        except OSError:
            mtime = None
        if mtime is not None and mtime != self._mtime:
            self._mtime, self._since, self.seen = mtime, now, True
        return now - self._since
