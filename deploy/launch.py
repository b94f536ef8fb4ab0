"""``c2farm launch``: every role as its own OS process on this machine, supervised.

- Each role runs ``python -m deploy.cli <role> --config runs/<run-id>/config.yaml``: a fresh
  interpreter (fork+exec, never a fork of a process holding a Zenoh session), in its own
  process group so a terminal's Ctrl-C reaches only the launcher, which then stops the
  roles.
- Output of every child is streamed with a prefix (``[actor-1] ...``) and also appended to
  ``runs/<run-id>/logs/<instance>.log``.
- The router starts first; the others start once it accepts connections.
- A role listed in ``launch.restart`` (every role, by default) that dies is restarted under
  the same name, the router on the same endpoint: every client session redials it and
  Zenoh re-declares their subscriptions and tokens, so the run carries on. The wait doubles
  per quick failure in a row, at most ``launch.max_restarts`` restarts per instance.
- A role alive as a process but silent (its beacon file, see ``deploy/liveness.py``, unchanged
  for ``launch.liveness_timeout_s``: SIGSTOPped, hung) is SIGKILLed, then restarted as above.
- SIGINT/SIGTERM: SIGTERM to every role at once (the router once they are gone, since it
  carries their last acks and statuses), SIGKILL to whatever is left at one deadline,
  ``launch.shutdown_grace_s`` after the start of the stop; the launcher returns once every
  child has exited (or, stuck in the kernel, been SIGKILLed), under 10 s in all.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import IO, Optional

from deploy.config import DEFAULT_INSTANCE, ONE_SHOT_ROLES, ROLES, RunConfig
from deploy.endpoints import loopback, tcp_endpoints, wait_for_listener
from deploy.liveness import BEACON_ENV, PARENT_ENV, BeaconWatch, beacon_path
from deploy.progress import progress_line


@dataclass
class Child:
    """One supervised role process (it keeps its name across restarts)."""

    role: str
    instance: str
    proc: Optional[subprocess.Popen] = None
    restarts: int = 0  #: restarts done so far
    quick_failures: int = 0  #: exits in a row soon after starting (the backoff exponent)
    started_at: float = 0.0  #: monotonic time of the last start
    restart_at: Optional[float] = None  #: monotonic time of a scheduled restart
    done: bool = False  #: exited and will not be restarted
    killed_silent: bool = False  #: the launcher killed it for a silent beacon
    beacon: Optional[BeaconWatch] = field(default=None, repr=False)
    reader: Optional[threading.Thread] = field(default=None, repr=False)

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None


class Launcher:
    """Starts, watches, restarts and stops the roles of one run on this machine."""

    def __init__(self, config: RunConfig, out: IO[str] = sys.stdout):
        self.config = config
        self.run_dir = config.run_dir
        self.out = out
        self._out_lock = threading.Lock()
        self.stop = threading.Event()
        self._signals = 0
        self._progress_thread: Optional[threading.Thread] = None
        self.started = time.monotonic()  #: when this launch began (the progress line's clock)
        self.children: list[Child] = []
        launch = config.launch
        for role in ROLES:
            if role not in launch.roles or (role == "demo_source" and config.demos.episodes == 0):
                continue
            prefix = launch.instance_prefix
            if role == "actor":
                self.children += [Child("actor", f"{prefix}actor-{i}") for i in range(launch.num_actors)]
            else:
                self.children.append(Child(role, prefix + DEFAULT_INSTANCE[role]))

    # -- output ----------------------------------------------------------------------

    def say(self, text: str, prefix: str = "launch") -> None:
        with self._out_lock:
            self.out.write(f"[{prefix}] {text}\n")
            self.out.flush()

    def _pump(self, child: Child, proc: subprocess.Popen) -> None:
        log_path = self.run_dir / "logs" / f"{child.instance}.log"
        with open(log_path, "a", encoding="utf-8") as log_file:
            for line in proc.stdout:  # ends when the child (and its fd copies) are gone
                log_file.write(line)
                log_file.flush()
                self.say(line.rstrip("\n"), prefix=child.instance)

    # -- processes -------------------------------------------------------------------

    def command(self, child: Child) -> list[str]:
        return [
            sys.executable,
            "-m",
            "deploy.cli",
            child.role,
            "--preset",
            "none",
            "--config",
            str(self.run_dir / "config.yaml"),
            "--run-id",
            self.config.run.run_id,
            "--instance",
            child.instance,
        ]

    def start(self, child: Child) -> None:
        (self.run_dir / "logs").mkdir(parents=True, exist_ok=True)
        if child.beacon is None:
            child.beacon = BeaconWatch(beacon_path(self.run_dir, child.instance))
        child.beacon.reset()
        env = dict(os.environ, PYTHONUNBUFFERED="1",
                   **{PARENT_ENV: str(os.getpid()), BEACON_ENV: str(child.beacon.path)})
        proc = subprocess.Popen(
            self.command(child),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
            bufsize=1,
            env=env,
            start_new_session=True,  # own process group: killpg reaches its helpers too
        )
        child.proc, child.restart_at, child.killed_silent = proc, None, False
        child.started_at = time.monotonic()
        child.reader = threading.Thread(target=self._pump, args=(child, proc), daemon=True)
        child.reader.start()
        self.say(f"started {child.instance} (pid {proc.pid})")

    def _on_signal(self, signum, _frame) -> None:
        self._signals += 1
        self.stop.set()
        if self._signals > 1:  # a second Ctrl-C: no more patience
            for child in self.children:
                self._kill(child, signal.SIGKILL)

    @staticmethod
    def _kill(child: Child, sig: int) -> None:
        if child.proc is None or child.proc.poll() is not None:
            return  # never signal a reaped pid: it may belong to someone else by now
        try:
            os.killpg(child.proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    # -- the run ---------------------------------------------------------------------

    def run(self) -> int:
        """Start everything, supervise until a signal, stop everything; return an exit code."""
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        code = 0
        first_launch = self.run_dir / "launched_at"  # a resumed run keeps its first start time
        if not first_launch.exists():
            first_launch.write_text(f"{time.time():.3f}\n")
        try:
            code = self._start_all()
            if code == 0:
                self._banner()
                code = self._supervise()
        finally:
            self._shutdown()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        return code

    def _start_all(self) -> int:
        for child in self.children:
            if self.stop.is_set():
                return 0
            self.start(child)
            if child.role == "router" and not self._router_ready(child):
                return 1
            if child.role == "dashboard":
                self._dashboard_ready(child)
        return 0

    def _dashboard_ready(self, dashboard: Child) -> None:
        """Wait until the dashboard serves HTTP, so it watches every role from its first status.

        It subscribes to the fabric before it serves; a role it never heard from (the demo source
        finishes in seconds) would be missing from its page. A dashboard that does not come up in
        ``launch.dashboard_wait_s`` is reported and the run goes on without waiting: training does
        not depend on it.
        """
        wait_s, port = self.config.launch.dashboard_wait_s, self.config.dashboard.port
        if wait_s <= 0 or port == 0:  # port 0: it picks its own, there is nothing to probe
            return
        endpoint = [loopback(f"tcp/{self.config.dashboard.host}:{port}")]
        deadline = time.monotonic() + wait_s
        while dashboard.alive and not self.stop.is_set() and time.monotonic() < deadline:
            if wait_for_listener(endpoint, 0.5, self.stop):
                return
        if not self.stop.is_set():
            self.say(f"the dashboard did not serve on port {port} within {wait_s:.0f} s; starting the rest anyway")

    def _router_ready(self, router: Child) -> bool:
        wait_s = self.config.launch.router_wait_s
        ready = threading.Event()

        def probe() -> None:
            if wait_for_listener(self.config.fabric.listen, wait_s, self.stop):
                ready.set()

        thread = threading.Thread(target=probe, daemon=True)
        thread.start()
        while thread.is_alive():
            if not router.alive:
                self.say(f"the router exited with code {router.proc.returncode}; is the port in use?")
                return False
            thread.join(0.1)
        if not ready.is_set() and not self.stop.is_set():
            self.say(f"the router did not listen on {self.config.fabric.listen} within {wait_s:.0f} s")
            return False
        return True

    def _banner(self) -> None:
        cfg = self.config
        self.say(f"run {cfg.run.run_id}: {self.run_dir}/ (config.yaml, versions.json, logs/)")
        if tcp_endpoints(cfg.fabric.listen) and "router" in cfg.launch.roles:
            self.say(f"zenoh router on {', '.join(cfg.fabric.endpoints('listen'))}")
        if cfg.fabric.secure:
            self.say(f"fabric: TLS with mutual authentication and access control ({cfg.fabric.certs})")
        elif cfg.fabric.insecure:
            self.say("fabric: INSECURE (plain TCP beyond loopback; every host that reaches the router is trusted)")
        if "dashboard" in cfg.launch.roles:
            self.say(f"dashboard: http://{cfg.dashboard.host}:{cfg.dashboard.port}/?token={self._dashboard_token()} "
                     "(the token opens the operator's commands, and every page beyond loopback)")
        self.say("press Ctrl-C to stop")

    def _supervise(self) -> int:
        launch = self.config.launch
        next_progress = time.monotonic() + launch.progress_every_s
        next_liveness = time.monotonic()
        while not self.stop.wait(0.2):
            now = time.monotonic()
            if launch.progress_every_s > 0 and now >= next_progress and "dashboard" in launch.roles:
                next_progress = now + launch.progress_every_s
                self._progress_soon()
            if launch.liveness_timeout_s > 0 and now >= next_liveness:
                next_liveness = now + 1.0
                self._kill_silent()
            for child in self.children:
                if child.done:
                    continue
                if child.restart_at is not None:
                    if now >= child.restart_at:
                        child.restarts += 1
                        self.start(child)
                    continue
                if child.alive:
                    continue
                self._on_exit(child, now)
            if self.children and all(c.done for c in self.children if c.role not in ONE_SHOT_ROLES):
                self.say("every role has exited")
                return 1
        return 0

    def _on_exit(self, child: Child, now: float) -> None:
        """A child's process ended: finished, restart it (with backoff), or give up on it."""
        launch = self.config.launch
        code = child.proc.returncode
        how = " (killed: silent)" if child.killed_silent else ""
        if child.role in ONE_SHOT_ROLES and code == 0:
            child.done = True
            self.say(f"{child.instance} finished its job")
        elif child.role in launch.restart and child.restarts < launch.max_restarts:
            if now - child.started_at >= launch.restart_backoff_max_s:
                child.quick_failures = 0  # it ran a good while: no penalty from older failures
            delay = min(launch.restart_backoff_s * 2**child.quick_failures, launch.restart_backoff_max_s)
            child.quick_failures += 1
            child.restart_at = now + delay
            self.say(
                f"{child.instance} exited with code {code}{how}; restart "
                f"{child.restarts + 1}/{launch.max_restarts} in {delay:.1f} s"
            )
        else:
            child.done = True
            why = "restart limit reached" if child.role in launch.restart else "not restarted"
            self.say(f"{child.instance} exited with code {code}{how} ({why})")

    def _kill_silent(self) -> None:
        """SIGKILL every running child whose beacon has been silent too long (hung, stopped).

        Not during a child's first ``liveness_grace_s``: a starting role may hold the GIL
        for long stretches (loading torch on a busy machine), which would look like silence.
        """
        launch = self.config.launch
        now = time.monotonic()
        for child in self.children:
            if not child.alive or child.killed_silent or child.beacon is None:
                continue
            silent = child.beacon.silent_for()
            if silent > launch.liveness_timeout_s and now - child.started_at > launch.liveness_grace_s:
                what = "silent" if child.beacon.seen else "never beat"
                self.say(f"{child.instance} (pid {child.proc.pid}) {what} for {silent:.0f} s "
                         "(hung or stopped); killing it")
                child.killed_silent = True
                self._kill(child, signal.SIGKILL)

    def _dashboard_token(self) -> str:
        """The dashboard's token (made now if the dashboard has not made it yet; it keeps the same file)."""
        from dashboard.access import ensure_token, token_path

        return ensure_token(token_path(self.run_dir, self.config.dashboard.token_file))

    def _progress_soon(self) -> None:
        """Print progress from a thread: a hung dashboard must not stall supervision."""
        if self._progress_thread is None or not self._progress_thread.is_alive():
            self._progress_thread = threading.Thread(target=self._progress, name="progress", daemon=True)
            self._progress_thread.start()

    def _progress(self) -> None:
        """One console line from the dashboard's summary (progress.py)."""
        import httpx

        logging.getLogger("httpx").setLevel(logging.WARNING)
        url = f"http://{self.config.dashboard.host}:{self.config.dashboard.port}/api/status"
        headers = {"Authorization": f"Bearer {self._dashboard_token()}"}  # needed beyond loopback
        try:  # a busy machine answers slowly
            summary = httpx.get(url, headers=headers, timeout=10.0).json().get("summary") or {}
        except (httpx.HTTPError, ValueError, AttributeError):
            return
        if summary:
            elapsed = time.monotonic() - self.started
            self.say("progress: " + progress_line(summary, elapsed, self.config.replay.min_size_to_sample,
                                                    insecure=self.config.fabric.insecure))

    def _shutdown(self) -> None:
        """SIGTERM every role, the router once they are gone; SIGKILL all left at the deadline.

        One deadline for the whole stop (``shutdown_grace_s``), not one per role or phase, so
        the total stays below it plus the moment SIGKILL takes to land.
        """
        if not any(c.alive for c in self.children):
            self._join_readers(time.monotonic() + 2.0)
            return
        self.say("stopping all roles")
        started = time.monotonic()
        grace = self.config.launch.shutdown_grace_s
        deadline = started + grace
        routers = [c for c in self.children if c.role == "router"]
        others = [c for c in self.children if c.role != "router"]
        for child in others:
            self._kill(child, signal.SIGTERM)
        # The router carries the others' last acks and "stopped" statuses; it stops in well
        # under a second, so it keeps a fifth of the grace (at most 1 s) for itself.
        self._wait(others, deadline - min(1.0, grace / 5))
        for child in routers:
            self._kill(child, signal.SIGTERM)
        self._wait(self.children, deadline)
        for child in self.children:
            if child.alive:
                self.say(f"{child.instance} did not stop within {grace:g} s; killing it")
                self._kill(child, signal.SIGKILL)  # the whole process group, helpers included
        # SIGKILL lands at once unless a process sits in the kernel (a large fsync); wait for
        # that only as long as keeps the whole stop under 10 s: it dies anyway, unattended.
        reap_by = max(time.monotonic(), deadline) + max(0.5, 9.5 - grace)
        for child in self.children:
            if child.proc is not None:
                try:
                    child.proc.wait(timeout=max(0.0, reap_by - time.monotonic()))
                except subprocess.TimeoutExpired:
                    self.say(f"{child.instance} (pid {child.proc.pid}) is still dying after SIGKILL")
        self._join_readers(reap_by + 0.2)
        self.say(f"all roles stopped in {time.monotonic() - started:.1f} s")

    @staticmethod
    def _wait(children: list[Child], deadline: float) -> None:
        while any(c.alive for c in children) and time.monotonic() < deadline:
            time.sleep(0.02)

    def _join_readers(self, deadline: float) -> None:
        for child in self.children:
            if child.reader is not None:
                child.reader.join(timeout=max(0.0, deadline - time.monotonic()))


def launch(config: RunConfig) -> int:
    """Run ``config`` on this machine until interrupted (the body of ``c2farm launch``)."""
    return Launcher(config).run()
