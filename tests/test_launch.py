"""`c2farm launch` end to end: every role as a real process, supervised, and stopped cleanly."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import httpx
import pytest
from conftest import REPO, Descendants, get_free_port, kill_launcher, stop_launcher, stop_process_tree, wait_for

from dashboard.registry import FabricFeed, RoleTable
from deploy.cli import build_parser
from protocol.fabric import FabricConfig, open_session

C2FARM = [sys.executable, "-m", "deploy.cli"]


class Output:
    """Collects a child's merged stdout/stderr in a thread (so its pipe never fills up)."""

    def __init__(self, proc: subprocess.Popen):
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc) -> None:
        for line in proc.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def text(self) -> str:
        return "\n".join(self.lines)


@pytest.mark.parametrize(
    "command", ["launch", "router", "replay", "learner", "actor", "eval", "demo_source", "dashboard"]
)
def test_every_subcommand_explains_its_options(command):
    result = subprocess.run(C2FARM + [command, "--help"], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert result.returncode == 0
    for option in ("--preset", "--config", "--set", "--run-id", "--connect", "--listen", "--print-config"):
        assert option in result.stdout
    parser = build_parser()
    subparser = next(a for a in parser._actions if a.dest == "command").choices[command]
    undocumented = [a.option_strings for a in subparser._actions if not a.help]
    assert not undocumented, f"options without a help text: {undocumented}"


def test_launch_runs_every_role_restarts_a_killed_actor_and_stops_clean(tmp_path: Path):
    router_port, dashboard_port, zmq_port = get_free_port(), get_free_port(), get_free_port()
    launcher = subprocess.Popen(
        C2FARM + [
            "launch", "--actors", "2", "--run-id", "launch-test", "--runs-dir", str(tmp_path),
            "--router-port", str(router_port), "--dashboard-port", str(dashboard_port),
            "--set", f"replay.zmq_endpoint=tcp://127.0.0.1:{zmq_port}",
            "--set", "launch.restart_backoff_s=3",  # long enough to watch the actor be gone
            "--set", "demos.episodes=0",  # training end to end is tests/test_training_e2e.py
            "--set", "launch.roles=[router,replay,dashboard,learner,actor]",
        ],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )
    output = Output(launcher)
    children = Descendants(launcher.pid)

    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{dashboard_port}", timeout=5) as http:

            def roles():
                try:
                    return {r["instance"]: r for r in http.get("/api/status").json()["roles"]}
                except httpx.HTTPError:
                    return {}

            expected = {"router", "replay", "learner", "actor-0", "actor-1", "dashboard"}
            everyone = wait_for(
                lambda: (r := roles()) and expected <= {n for n, v in r.items() if v["alive"] and v["pid"]} and r,
                90, "every role to report alive on /api/status",
            )
            assert http.get("/healthz").json()["ok"] is True
            children.scan()

            victim = everyone["actor-1"]["pid"]
            assert victim in children.seen  # it is the launcher's child, not some other process
            os.kill(victim, signal.SIGKILL)
            gone = wait_for(lambda: (r := roles()) and not r["actor-1"]["alive"] and r["actor-1"], 15,
                            "the killed actor to show as gone")
            assert gone["state"] == "gone" and gone["losses"] >= 1
            assert roles()["actor-0"]["alive"]  # the others carry on
            back = wait_for(
                lambda: (
                    (r := roles())
                    and r["actor-1"]["alive"]
                    and r["actor-1"]["pid"] not in (None, victim)
                    and r["actor-1"]
                ),
                60,
                "the actor to be restarted",
            )
            assert back["starts"] >= 2
            children.scan()

        stop_launcher(launcher, children)
    finally:
        kill_launcher(launcher, children)

    text = output.text
    assert f"dashboard: http://127.0.0.1:{dashboard_port}/" in text
    assert "[actor-0]" in text and "[replay]" in text  # role-prefixed log lines
    assert "actor-1 exited with code -9; restart 1/" in text
    run_dir = tmp_path / "launch-test"
    assert (run_dir / "config.yaml").exists() and (run_dir / "versions.json").exists()
    assert (run_dir / "logs" / "actor-1.log").exists()


def test_roles_can_be_started_one_by_one_by_hand(tmp_path: Path):
    endpoint = f"tcp/127.0.0.1:{get_free_port()}"
    common = ["--run-id", "by-hand", "--runs-dir", str(tmp_path)]
    router = subprocess.Popen(C2FARM + ["router", "--listen", endpoint] + common, cwd=REPO,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    actor = subprocess.Popen(C2FARM + ["actor", "--connect", endpoint, "--instance", "actor-7"] + common, cwd=REPO,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    table = RoleTable("by-hand")
    session = feed = None
    try:
        wait_for(lambda: _can_connect(endpoint), 30, "the router to listen")
        session = open_session(FabricConfig(connect=[endpoint]))
        feed = FabricFeed(session, "by-hand", table)
        wait_for(lambda: {r["instance"] for r in table.snapshot()["roles"] if r["alive"]} == {"router", "actor-7"},
                 30, "router and actor-7 to be alive")
        actor.send_signal(signal.SIGTERM)
        assert actor.wait(timeout=15) == 0
        wait_for(lambda: not next(r for r in table.snapshot()["roles"] if r["instance"] == "actor-7")["alive"],
                 10, "actor-7 to be gone after a clean stop")
    finally:
        if feed is not None:
            feed.close()
        if session is not None:
            session.close()
        stop_process_tree(actor)
        stop_process_tree(router)
    assert router.returncode == 0
    assert (tmp_path / "by-hand" / "config.yaml").exists()


def test_a_role_without_a_router_fails_clearly(tmp_path: Path):
    result = subprocess.run(
        C2FARM + ["learner", "--run-id", "r", "--runs-dir", str(tmp_path), "--connect",
                  f"tcp/127.0.0.1:{get_free_port()}", "--set", "launch.router_wait_s=0.5"],
        capture_output=True, text=True, cwd=REPO, timeout=60,
    )
    assert result.returncode == 2
    assert "no Zenoh router answers" in result.stderr


def test_a_role_needs_a_run_id():
    result = subprocess.run(C2FARM + ["actor"], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert result.returncode == 2 and "run.run_id: not set" in result.stderr



def _refused(args: list[str], tmp_path: Path) -> list[str]:
    """Run ``c2farm <args>``; it must exit 2 without starting anything; returns its stderr lines."""
    result = subprocess.run(C2FARM + args, capture_output=True, text=True, cwd=REPO, timeout=120)
    lines = [line for line in result.stderr.splitlines() if line.startswith("c2farm")]
    assert result.returncode == 2, result.stderr[-2000:]
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir()), "a run directory was made"
    return lines


def test_a_launch_that_cannot_work_is_refused_up_front_in_one_line(tmp_path: Path):
    runs = ["--runs-dir", str(tmp_path / "runs"), "--router-port", "0", "--dashboard-port", "0",
            "--set", f"replay.zmq_endpoint=tcp://127.0.0.1:{get_free_port()}"]
    [line] = _refused(["launch", "--task", "no_such_task", *runs], tmp_path)
    assert "unknown task 'no_such_task'" in line and "push_button" in line
    [line] = _refused(["launch", "--config", str(tmp_path / "missing.yaml"), *runs], tmp_path)
    assert "missing.yaml: cannot read (No such file or directory)" in line
    [line] = _refused(["launch", "--set", "qattention.cameras=[wrist]", *runs], tmp_path)
    assert "qattention.cameras" in line and "set sim.cameras instead" in line
    with socket.socket() as taken:  # another run's dashboard
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        [line] = _refused(["launch", *runs, "--dashboard-port", str(port)], tmp_path)
    assert f"dashboard.port: cannot listen on 127.0.0.1:{port}" in line


def test_demos_refuses_counts_that_make_no_sense(tmp_path: Path):
    for bad in (["--episodes", "-1"], ["--episodes", "0"], ["--image-size", "0"], ["--seed", "-3"]):
        result = subprocess.run(C2FARM + ["demos", "--task", "push_button", "--out", str(tmp_path / "d"), *bad],
                                capture_output=True, text=True, cwd=REPO, timeout=60)
        assert result.returncode == 2 and "must be" in result.stderr, (bad, result.stderr)
        assert not (tmp_path / "d").exists()


def _can_connect(endpoint: str) -> bool:
    import socket

    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    try:
        with socket.create_connection((host, int(port)), timeout=1):
            return True
    except OSError:
        return False


def test_every_role_is_restarted_by_default_the_router_and_dashboard_too():
    from deploy.config import ROLES, LaunchConfig

    assert set(LaunchConfig().restart) == set(ROLES)


class _ScriptLauncher:
    """A Launcher whose roles are tiny Python scripts (no torch, no Zenoh): supervision alone."""

    @staticmethod
    def make(tmp_path: Path, script: str, **launch):
        from deploy.config import RunConfig
        from deploy.launch import Launcher

        config = RunConfig()
        config.run.run_id, config.run.runs_dir = "tiny", str(tmp_path)
        config.launch.roles = ["replay"]
        for key, value in launch.items():
            setattr(config.launch, key, value)
        config.run_dir.mkdir(parents=True)

        class Tiny(Launcher):
            def command(self, child):
                return [sys.executable, "-c", script]

        out = _Lines()
        return Tiny(config, out=out), out


class _Lines:
    def __init__(self):
        self.lines: list[str] = []

    def write(self, text: str) -> None:
        self.lines.extend(line for line in text.splitlines() if line)

    def flush(self) -> None:
        pass

    def has(self, text: str) -> bool:
        return any(text in line for line in list(self.lines))


BEATING = "from deploy.liveness import start_beacon_from_env; start_beacon_from_env(); import time; time.sleep(120)"


def test_a_silent_role_is_killed_and_restarted(tmp_path: Path):
    launcher, out = _ScriptLauncher.make(tmp_path, BEATING, liveness_timeout_s=1.0, liveness_grace_s=3.0,
                                         restart_backoff_s=0.1)
    child = launcher.children[0]
    pids: list[int] = []

    def inject() -> None:
        try:
            wait_for(lambda: child.alive and child.beacon.path.exists(), 60, "the role to beat")
            pids.append(child.proc.pid)
            os.kill(child.proc.pid, signal.SIGSTOP)
            wait_for(lambda: child.alive and child.proc.pid != pids[0], 60, "a new process")
            pids.append(child.proc.pid)
        finally:
            launcher.stop.set()

    thread = threading.Thread(target=inject, daemon=True)
    thread.start()
    assert launcher.run() == 0  # signal handlers need the main thread, so the launcher runs here
    thread.join(5)
    assert len(pids) == 2, out.lines
    assert out.has(f"replay (pid {pids[0]}) silent for") and out.has("(killed: silent); restart 1/")
    assert out.has("all roles stopped in")
    assert not child.alive


def test_a_stop_kills_a_role_that_ignores_sigterm_at_the_deadline(tmp_path: Path):
    stubborn = (
        "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); time.sleep(120)"
    )
    launcher, out = _ScriptLauncher.make(tmp_path, stubborn, shutdown_grace_s=1.0)
    child = launcher.children[0]

    def stop_soon() -> None:
        wait_for(lambda: out.has("[replay] up"), 30, "the role to start")
        launcher.stop.set()

    threading.Thread(target=stop_soon, daemon=True).start()
    assert launcher.run() == 0
    assert out.has("replay did not stop within 1 s; killing it") and out.has("all roles stopped in")
    assert child.proc.returncode == -signal.SIGKILL


def test_the_roles_after_the_dashboard_start_once_it_serves(tmp_path: Path):
    """The dashboard must hear every role from its first status: a demo source may be done in seconds."""
    from deploy.endpoints import free_port

    port = free_port()
    slow_dashboard = ("import socket, time; time.sleep(2); s = socket.create_server(('127.0.0.1', %d)); "
                      "print('serving', flush=True); time.sleep(120)" % port)
    launcher, out = _ScriptLauncher.make(tmp_path, "", roles=["dashboard", "learner"])
    launcher.config.dashboard.port = port
    launcher.command = lambda child: [sys.executable, "-c", slow_dashboard if child.role == "dashboard" else
                                      "print('up', flush=True); import time; time.sleep(120)"]

    def stop_soon() -> None:
        wait_for(lambda: out.has("[learner] up"), 60, "the learner to start")
        launcher.stop.set()

    threading.Thread(target=stop_soon, daemon=True).start()
    assert launcher.run() == 0
    started = [line for line in out.lines if "started learner" in line or "[dashboard] serving" in line]
    assert started[0] == "[dashboard] serving", out.lines
