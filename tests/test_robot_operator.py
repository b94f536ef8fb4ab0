"""The person in the loop: operator commands on the wire, from the dashboard and a terminal, to a robot actor."""

from __future__ import annotations

import io
import os
import pty
import subprocess
import sys
import termios
import textwrap
import threading
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from actors.robot.operator import FabricOperator, OperatorChannel, TerminalOperator
from dashboard.app import create_app
from dashboard.operator_buttons import OperatorPublisher
from dashboard.registry import RoleTable
from protocol.codec import ProtocolError
from protocol.fabric import open_session
from protocol.messages import OperatorAction, OperatorCommand, decode, encode, encode_unchecked

TOKEN = "operator-test-token-0123456789"


def test_operator_command_round_trips():
    command = OperatorCommand("robot-0", OperatorAction.RESET_DONE, seq=7, time=1.5, source="dashboard")
    assert decode(encode(command), expect=OperatorCommand) == command


@pytest.mark.parametrize("bad, field", [
    (OperatorCommand("robot/0", OperatorAction.STOP), "actor"),  # would reshape the key
    (OperatorCommand("robot-0", "dance"), "action"),
    (OperatorCommand("robot-0", OperatorAction.STOP, seq=-1), "seq"),
    (OperatorCommand("robot-0", OperatorAction.STOP, time=float("nan")), "time"),
])
def test_malformed_operator_commands_are_refused(bad, field):
    with pytest.raises(ProtocolError) as err:
        decode(encode_unchecked(bad), expect=OperatorCommand)
    assert err.value.field == field


def test_stop_acts_at_once_and_verdicts_wait_in_order():
    calls = []
    channel = OperatorChannel(on_stop=lambda: calls.append("stop"), on_resume=lambda: calls.append("resume"))
    channel.put(OperatorAction.FAIL)
    channel.put(OperatorAction.RESET_DONE)
    channel.put(OperatorAction.STOP)
    assert calls == ["stop"] and channel.paused
    never = threading.Event()
    assert channel.wait_for({OperatorAction.RESET_DONE}, never, timeout_s=0.3) is None  # paused: nothing is handed out
    channel.put(OperatorAction.RESUME)
    assert calls == ["stop", "resume"] and not channel.paused
    assert channel.wait_for({OperatorAction.RESET_DONE}, never, timeout_s=1) is OperatorAction.RESET_DONE
    assert channel.take({OperatorAction.SUCCESS, OperatorAction.FAIL}) is OperatorAction.FAIL
    assert channel.take({OperatorAction.FAIL}) is None


def test_terminal_words_reach_the_channel():
    channel = OperatorChannel()
    TerminalOperator(io.StringIO("r\nnonsense\nsuccess\nx\n"), channel)
    deadline = time.monotonic() + 5
    while not channel.paused and time.monotonic() < deadline:
        time.sleep(0.01)
    assert channel.paused
    assert channel.take({OperatorAction.RESET_DONE}) is OperatorAction.RESET_DONE
    assert channel.take({OperatorAction.SUCCESS}) is OperatorAction.SUCCESS


def _until(condition, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)
    return condition()


@pytest.fixture
def terminal():
    """A pseudo-terminal: (the operator's keyboard side, the actor's side as a text stream)."""
    keyboard, actor_side = pty.openpty()
    with open(actor_side, "r", closefd=False) as stream:
        yield keyboard, stream
    os.close(keyboard)
    os.close(actor_side)


def test_a_single_key_acts_on_a_terminal_without_enter(terminal):
    keyboard, stream = terminal
    settings = termios.tcgetattr(stream)
    calls = []
    channel = OperatorChannel(on_stop=lambda: calls.append("stop"), on_resume=lambda: calls.append("resume"))
    with TerminalOperator(stream, channel) as operator:
        assert not termios.tcgetattr(stream)[3] & termios.ICANON  # cbreak: keys arrive one by one
        assert "Enter" not in operator.help
        os.write(keyboard, b"x")  # no newline: the stop is the key itself
        assert _until(lambda: channel.paused) and calls == ["stop"]
        os.write(keyboard, b"c")
        assert _until(lambda: not channel.paused) and calls == ["stop", "resume"]
        os.write(keyboard, b"r ")  # space stops too
        assert _until(lambda: channel.paused) and calls == ["stop", "resume", "stop"]
        assert channel.take({OperatorAction.RESET_DONE}) is OperatorAction.RESET_DONE
    assert termios.tcgetattr(stream) == settings


def test_the_terminal_is_restored_when_the_actor_fails(terminal):
    _, stream = terminal
    settings = termios.tcgetattr(stream)
    with pytest.raises(RuntimeError), TerminalOperator(stream, OperatorChannel()):
        assert termios.tcgetattr(stream) != settings
        raise RuntimeError("the arm went away")
    assert termios.tcgetattr(stream) == settings


def test_the_terminal_is_restored_when_the_actor_is_signalled(terminal):
    """As ``c2farm robot`` ends: SIGTERM sets the role's stop, the role unwinds, then ``os._exit``."""
    _, stream = terminal
    settings = termios.tcgetattr(stream)
    child = textwrap.dedent("""
        import os, sys, threading
        from actors.robot.operator import OperatorChannel, TerminalOperator
        from protocol.role import stop_on_signals
        stop = threading.Event()
        stop_on_signals(stop)
        with open(sys.argv[1]) as terminal, TerminalOperator(terminal, OperatorChannel()):
            print("keys", flush=True)
            stop.wait()
        os._exit(0)
    """)
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-c", child, os.ttyname(stream.fileno())], cwd=root,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "keys"
        assert not termios.tcgetattr(stream)[3] & termios.ICANON
        proc.terminate()
        assert proc.wait(timeout=10) == 0
    finally:
        proc.kill()
    assert termios.tcgetattr(stream) == settings


def test_dashboard_buttons_reach_the_robot_actor_over_zenoh(router):
    """HTTP POST -> dashboard's Zenoh session -> router -> the robot actor's subscriber -> its channel."""
    dash, robot = open_session(router), open_session(router)
    try:
        channel = OperatorChannel()
        listener = FabricOperator(robot, "run1", "robot-0", channel)
        other = OperatorChannel()
        FabricOperator(robot, "run1", "robot-1", other)
        app = create_app(RoleTable("run1"), token=TOKEN)
        http = TestClient(app, headers={"Authorization": f"Bearer {TOKEN}"})  # a command needs the token
        assert http.post("/api/operator/robot-0/success").status_code == 503  # no session installed yet
        app.state.operator = OperatorPublisher(dash, "run1")
        time.sleep(0.5)  # let the subscriptions reach the router
        assert TestClient(app).post("/api/operator/robot-0/stop").status_code == 401  # without it: never sent
        for action in ("reset_done", "success"):
            answer = http.post(f"/api/operator/robot-0/{action}")
            assert answer.status_code == 202 and answer.json()["action"] == action
        assert http.post("/api/operator/robot-0/dance").status_code == 404
        never = threading.Event()
        assert channel.wait_for({OperatorAction.RESET_DONE}, never, timeout_s=10) is OperatorAction.RESET_DONE
        assert channel.wait_for({OperatorAction.SUCCESS}, never, timeout_s=10) is OperatorAction.SUCCESS
        assert other.take(set(OperatorAction)) is None  # only the addressed actor hears it
        listener.close()
    finally:
        robot.close()
        dash.close()


def test_the_dashboard_app_serves_the_operator_buttons():
    app = create_app(RoleTable("run1"), token=TOKEN)
    http = TestClient(app)
    assert http.post("/api/operator/robot-0/stop").status_code == 401  # a command always needs the token
    answer = http.post("/api/operator/robot-0/stop", headers={"Authorization": f"Bearer {TOKEN}"})
    assert answer.status_code == 503  # past the token: refused until the role installs its session
    assert create_app(RoleTable("run1")).state.access.token != create_app(RoleTable("run1")).state.access.token
    # without a token given, a random one nobody holds: no command gets through
