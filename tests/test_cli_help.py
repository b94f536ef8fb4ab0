"""What a new user sees first: ``--help`` that names the real choices, and no library banners."""

import subprocess
import sys

from conftest import REPO


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=120)


def test_launch_help_lists_the_tasks_the_default_roles_and_what_it_restarts():
    out = run("-m", "deploy.cli", "launch", "--help")
    assert out.returncode == 0
    text = " ".join(out.stdout.split())  # argparse wraps lines
    assert "pick_and_lift" in text and "(default: reach_target)" in text
    assert "default: router,replay,dashboard,learner,demo_source,actor,eval" in text
    assert "restart every role that dies" in text
    assert "pybullet build time" not in out.stdout + out.stderr


def test_the_simulator_loads_without_printing_a_banner():
    out = run(
        "-c", "from actors.panda_env import PandaEnv; from actors.sim import SimConfig; PandaEnv(SimConfig()).close()"
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout == "" and "pybullet build time" not in out.stderr
