"""A real robot is one more actor: router, replay, learner, dashboard, demo source and a robot actor on franky-sim.

First ``c2farm robot-demos`` records a demo on franky-sim (the scripted operator demonstrates its
reach). Then every role is a real process started by ``c2farm launch --robot franky-sim --camera
mujoco``: the demo source sends the robot demo like a simulated one, the robot actor drives
franky-sim through franky over libfranka's protocol and sees the scene through the MuJoCo RGB-D
stand-in. The test is the person: it says "reset done", "success" and "fail" through the
dashboard's HTTP API. Demo and robot episodes reach the one replay, the learner trains on both
(each sample voxelised in the robot's own box, which every observation carries), the robot actor
follows newer weights and, with ``robot.evaluate``, scores them greedily into metrics/eval.csv.
The learner and the replay are the unchanged roles.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import httpx
import pytest
from conftest import (
    REPO,
    TINY_TRAINING,
    Descendants,
    get_free_port,
    kill_launcher,
    status_reader,
    stop_launcher,
    wait_for,
)

pytest.importorskip("franky")
pytest.importorskip("franky_sim")


@pytest.mark.timeout(900)
def test_robot_actor_feeds_the_replay_and_follows_weights(tmp_path: Path):
    # The demo and the launch below both move at half the Panda's dynamics (the default is a tenth): a shorter test.
    robot_demos = ["--robot", "franky-sim", "--camera", "mujoco", "--task", "reach_target",
                   "--set", f"demos.directory={tmp_path / 'demos'}", "--set", "demos.episodes=1",
                   "--set", "robot.franka.dynamics_factor=0.5"]
    recorded = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "robot-demos", *robot_demos, "--set", "robot.scripted_operator=true"],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )
    assert recorded.returncode == 0, recorded.stdout + recorded.stderr
    assert "1 robot demos in" in recorded.stdout

    ports = {name: get_free_port() for name in ("router", "dashboard", "zmq")}
    launcher = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "launch", "--run-id", "robot-e2e", "--runs-dir", str(tmp_path / "runs"),
         "--router-port", str(ports["router"]), "--dashboard-port", str(ports["dashboard"]),
         "--set", f"replay.zmq_endpoint=tcp://127.0.0.1:{ports['zmq']}",
         "--roles", "router,replay,dashboard,learner,demo_source,robot", *robot_demos, *TINY_TRAINING,
         "--set", "robot.verdict_wait_s=1",
         "--set", "actor.weights_wait_s=1", "--set", "launch.liveness_grace_s=180",
         "--set", "robot.evaluate=true", "--set", "actor.eval_episodes=1", "--set", "actor.eval_min_episodes=1",
         "--set", "actor.eval_every_versions=1"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(line.rstrip() for line in launcher.stdout), daemon=True).start()
    children = Descendants(launcher.pid)
    done = threading.Event()
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{ports['dashboard']}", timeout=5) as http:

            status = status_reader(http, children)

            token_file = tmp_path / "runs" / "robot-e2e" / "dashboard.token"

            def operator() -> None:
                """The person: resets the scene, and judges every other episode a success.

                Commands carry the dashboard's token, as from the URL the launcher prints.
                """
                n = 0
                with httpx.Client(base_url=http.base_url, timeout=5) as buttons:
                    while not done.wait(1.0):
                        if not token_file.exists():
                            continue
                        n += 1
                        bearer = {"Authorization": f"Bearer {token_file.read_text().strip()}"}
                        for action in ("reset_done", "success" if n % 2 else "fail"):
                            try:
                                buttons.post(f"/api/operator/robot-0/{action}", headers=bearer)
                            except httpx.HTTPError:
                                pass

            threading.Thread(target=operator, daemon=True).start()
            first = wait_for(
                lambda: (s := status()) and s.get("robot-0", {}).get("counters", {}).get("acked", 0) >= 2 and s,
                420, "two robot episodes stored by the replay",
            )
            robot = first["robot-0"]["counters"]
            assert robot["episodes"] >= 2 and robot["operator_reset_done"] >= 2
            # the robot's episodes beside the demo's, in one replay; the replay's counters reach the status on its
            # own heartbeat, so an episode the robot saw acked can show there a beat later
            wait_for(lambda: (s := status()) and s["replay"]["counters"].get("demo_transitions", 0) > 0
                     and s["replay"]["counters"].get("agent_transitions", 0) > 0, 120,
                     "the robot demo and the robot's episodes in the replay")
            wait_for(
                lambda: (s := status()) and (s["summary"]["updates"] or 0) >= 2
                and s["robot-0"]["counters"].get("weights_version", 0) >= 2 and s,
                420, "learner updates and a newer weights version at the robot actor",
            )
            evaluations = tmp_path / "runs" / "robot-e2e" / "metrics" / "eval.csv"
            wait_for(lambda: evaluations.exists() and len(evaluations.read_text().splitlines()) >= 2, 420,
                     "a greedy evaluation on the robot")
            row = dict(zip(*[line.split(",") for line in evaluations.read_text().splitlines()[:2]]))
            assert int(row["weights_version"]) >= 1 and int(row["episodes"]) == 1
            assert status()["replay"]["counters"]["demo_transitions_sampled"] > 0  # the learner trained on the demo
        done.set()
        stop_launcher(launcher, children)
    finally:
        done.set()
        kill_launcher(launcher, children)
        print("\n".join(lines[-60:]))
