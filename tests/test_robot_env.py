"""RobotEnv: franky-sim's arm with the simulator's reset/step shape, the reward from an operator.

The scripted reach operator stands in for the person here (it says "reset done" after moving
the target, "success" when the grasp frame is within 2 cm of it); a person's words take the
same channel. Every observation carries the robot's depth-0 box, the safety workspace by default.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

pytest.importorskip("franky")
pytest.importorskip("franky_sim")

from actors.environment import SUCCESS_REWARD  # noqa: E402
from actors.robot.config import FrankaConfig, RobotConfig, SafetyConfig  # noqa: E402
from actors.robot.env import OperatorStopped, RobotEnv  # noqa: E402
from actors.robot.franka import FrankaArm  # noqa: E402
from actors.robot.franky_sim import FrankySim  # noqa: E402
from actors.robot.operator import OperatorChannel  # noqa: E402
from actors.robot.reach_operator import ReachOperator  # noqa: E402
from actors.robot.safety import Safety  # noqa: E402
from protocol.episode import stack_observations  # noqa: E402
from protocol.messages import OperatorAction  # noqa: E402
from qattention.batch import ObservationBatch  # noqa: E402

DOWN = [1.0, 0.0, 0.0, 0.0]


@pytest.fixture
def rig():
    stop = threading.Event()
    with FrankySim() as sim:
        arm = FrankaArm(FrankaConfig(host=sim.hostname, dynamics_factor=0.3), SafetyConfig(), [sim.camera("front")])
        arm.connect()
        channel = OperatorChannel(on_stop=arm.stop, on_resume=arm.resume)
        env = RobotEnv(arm, channel, RobotConfig(arm="franky-sim", verdict_wait_s=0.5), "reach_target", 2, stop,
                       scripted=ReachOperator(sim, channel))
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


def test_every_observation_carries_the_robot_box_to_the_learner(rig):
    env, sim, _ = rig
    box = (0.2, -0.4, 0.0, 0.75, 0.4, 0.6)  # the default safety workspace, from the table top (z = 0) up
    first = env.reset(seed=8)
    last = env.step(np.array([*sim.target, *DOWN, 1.0])).observation
    # On the wire and in a batch: ``extra_scene_bounds`` per observation; the learner voxelises
    # each sample in the box it carries, whatever its own config says.
    batch = ObservationBatch.from_arrays(stack_observations([first, last]), ["front"])
    assert batch.bounds((-0.1, -0.5, -0.05, 0.9, 0.5, 0.95)).numpy() == pytest.approx(np.array([box, box]))


def test_the_default_box_holds_only_poses_the_safety_limits_let_through():
    robot = RobotConfig(arm="franky-sim")
    lo, hi = np.array(robot.depth0_bounds[:3]), np.array(robot.depth0_bounds[3:])
    voxels = 16
    centres = lo + (np.stack(np.meshgrid(*[np.arange(voxels)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) \
        * (hi - lo) / voxels
    safety = Safety(robot.safety)
    assert all(safety.allows(np.array([*c, *DOWN]), c) for c in centres)  # from where it stands: no step limit


def test_scene_bounds_are_six_numbers_with_min_below_max():
    assert RobotConfig(scene_bounds=[0.3, -0.2, 0.0, 0.6, 0.2, 0.4]).depth0_bounds == (0.3, -0.2, 0.0, 0.6, 0.2, 0.4)
    for bad in ([0.3, -0.2, 0.0], [0.6, -0.2, 0.0, 0.3, 0.2, 0.4], [0, 0, 0, float("nan"), 1, 1]):
        with pytest.raises(ValueError, match="scene"):
            RobotConfig(scene_bounds=bad)
    with pytest.raises(ValueError, match="table top"):
        RobotConfig(safety=SafetyConfig(table_height=0.7))  # above the workspace: an empty box


def test_greedy_evaluations_take_at_most_their_share_of_the_arms_time():
    """One arm both trains and evaluates: a 60 s evaluation at share 0.5 earns 60 s of training first."""
    from actors.config import ActorConfig
    from actors.robot.actor import evaluation_due, training_resumes_until

    assert training_resumes_until(100.0, 160.0, 0.5) == pytest.approx(220.0)
    assert training_resumes_until(100.0, 160.0, 0.25) == pytest.approx(340.0)
    assert training_resumes_until(100.0, 160.0, 1.0) == pytest.approx(160.0)  # evaluate whenever due
    config = ActorConfig(eval_every_versions=5)
    assert evaluation_due(1, 0, config) and evaluation_due(6, 1, config) and not evaluation_due(5, 1, config)
    with pytest.raises(ValueError, match="eval_share"):
        RobotConfig(eval_share=0.0)
