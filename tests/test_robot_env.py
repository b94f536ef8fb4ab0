"""RobotEnv: franky-sim's arm with the simulator's reset/step shape, the reward from an operator.

The scripted reach operator stands in for the person here (it says "reset done" after moving
the target, "success" when the grasp frame is within 2 cm of it); a person's words take the
same channel.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

pytest.importorskip("franky")
pytest.importorskip("franky_sim")

from actors.robot.config import FrankaConfig, RobotConfig, SafetyConfig  # noqa: E402
from actors.robot.env import OperatorStopped, ReachOperator, RobotEnv  # noqa: E402
from actors.robot.franka import FrankaArm  # noqa: E402
from actors.robot.franky_sim import FrankySim  # noqa: E402
from actors.robot.operator import OperatorChannel  # noqa: E402
from actors.sim.env import SUCCESS_REWARD  # noqa: E402
from protocol.messages import OperatorAction  # noqa: E402

DOWN = [1.0, 0.0, 0.0, 0.0]
BOUNDS = (0.0, -0.5, 0.0, 1.0, 0.5, 1.0)


@pytest.fixture
def rig():
    stop = threading.Event()
    with FrankySim() as sim:
        arm = FrankaArm(FrankaConfig(host=sim.hostname, dynamics_factor=0.3), SafetyConfig(), [sim.camera("front")])
        arm.connect()
        channel = OperatorChannel(on_stop=arm.stop, on_resume=arm.resume)
        env = RobotEnv(arm, channel, RobotConfig(arm="franky-sim", verdict_wait_s=0.5), "reach_target", 2, BOUNDS,
                       stop, scripted=ReachOperator(sim, channel))
        yield env, sim, channel
        stop.set()
        env.close()


def test_reaching_the_target_is_a_success_the_operator_rewards(rig):
    env, sim, _ = rig
    obs = env.reset(seed=3)
    assert set(obs.cameras) == {"front"} and obs.cameras["front"].rgb.shape == (128, 128, 3)
    assert np.linalg.norm(obs.gripper_pose[:3] - env.config.home[:3]) < 0.01  # every episode starts at home
    step = env.step(np.array([*sim.target, *DOWN, 1.0]))
    assert (step.reward, step.terminal, step.success, step.unreachable) == (SUCCESS_REWARD, True, True, False)


def test_missing_the_target_ends_as_a_timeout_with_no_reward(rig):
    env, sim, _ = rig
    env.reset(seed=4)
    away = sim.target + [0.0, 0.0, 0.1]
    first = env.step(np.array([*away, *DOWN, 1.0]))
    assert (first.reward, first.terminal) == (0.0, False)
    last = env.step(np.array([*away, *DOWN, 0.0]))
    assert (last.reward, last.terminal, last.success, last.info["timeout"]) == (0.0, True, False, True)


def test_a_refused_pose_ends_the_episode_as_unreachable(rig):
    env, _, _ = rig
    env.reset(seed=5)
    assert not env.reachable(np.array([0.5, 0.0, -0.2, *DOWN, 1.0]))
    step = env.step(np.array([0.5, 0.0, -0.2, *DOWN, 1.0]))
    assert (step.terminal, step.unreachable, step.info["reason"]) == (True, True, "below_table")


def test_an_operator_stop_drops_the_episode_and_pauses_until_resume(rig):
    env, _, channel = rig
    env.reset(seed=6)
    raised = []

    def move() -> None:
        try:
            env.step(np.array([0.6, -0.25, 0.35, *DOWN, 1.0]))
        except OperatorStopped as why:
            raised.append(why)

    mover = threading.Thread(target=move)
    mover.start()
    threading.Timer(0.5, channel.put, (OperatorAction.STOP, "test")).start()
    mover.join(timeout=60)
    assert raised and channel.paused and env.arm.stopped
    with pytest.raises(OperatorStopped):
        env.step(np.array([0.45, 0.0, 0.3, *DOWN, 1.0]))  # paused: nothing moves
    channel.put(OperatorAction.RESUME, "test")
    env.reset(seed=7)
    assert env.step(np.array([0.45, 0.0, 0.3, *DOWN, 1.0])).unreachable is False
