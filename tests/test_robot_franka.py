"""The Franka robot interface against franky-sim, through franky, over libfranka's real protocol.

Every test starts its own franky-sim (MuJoCo, 1 kHz, a loopback address of its own) and drives
it only through ``FrankaArm``; the simulator's own physics state is read as ground truth. The
bounds on times are safety nets for a busy 2-core CI machine, not performance claims (the
measured numbers are in BENCHMARKS.md).
"""

from __future__ import annotations

import dataclasses
import re
import threading
import time

import numpy as np
import pytest

pytest.importorskip("franky")
pytest.importorskip("franky_sim")

from actors.robot.config import FrankaConfig, SafetyConfig  # noqa: E402
from actors.robot.franka import FrankaArm  # noqa: E402
from actors.robot.franky_sim import FrankySim  # noqa: E402
from actors.robot.interface import RobotArm  # noqa: E402

TOP_DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # xyzw: the hand's z axis pointing at the table


@pytest.fixture
def sim():
    with FrankySim() as s:
        yield s


@pytest.fixture
def arm(sim):
    arm = FrankaArm(FrankaConfig(host=sim.hostname, dynamics_factor=0.2), SafetyConfig(), [sim.camera("front")])
    arm.connect()
    yield arm
    arm.disconnect()


def pose(x, y, z):
    return np.concatenate([[x, y, z], TOP_DOWN])


def test_franka_arm_is_a_robot_arm(arm):
    assert isinstance(arm, RobotArm)


def test_reachable_pose_is_reached_within_tolerance(arm):
    result = arm.move_to(pose(0.45, 0.1, 0.3), gripper_open=False)
    assert result.status == "reached", result
    assert result.position_error < arm.config.reach_tolerance
    obs = arm.observe()
    assert np.linalg.norm(obs.gripper_pose[:3] - [0.45, 0.1, 0.3]) < arm.config.reach_tolerance
    assert abs(abs(float(np.dot(obs.gripper_pose[3:], TOP_DOWN))) - 1.0) < 1e-3  # same orientation, either sign
    assert obs.gripper_open == 0.0 and obs.finger_positions.max() < 0.01  # closed on nothing


def test_a_refused_trajectory_is_planned_again_slower(sim):
    # 1e-12 of the dynamics makes a trajectory too long for Ruckig: franky refuses it for real (Ruckig's
    # calculation errors -1xx: -101 on some hosts, -110 on others), as it refused the same move of fresh simulations
    # on some hosts; the retry at full speed then moves the arm.
    config = FrankaConfig(host=sim.hostname, dynamics_factor=0.2, replan_dynamics=(1e-12, 1.0))
    arm = FrankaArm(config, SafetyConfig())
    arm.connect()
    try:
        result = arm.move_to(pose(0.45, -0.1, 0.3), gripper_open=True)
        assert result.status == "reached", result
        assert arm.counters["replans"] == 1
        arm.config = dataclasses.replace(config, replan_dynamics=(1e-12,))  # no retry left: the refusal is the result
        refused = arm.move_to(pose(0.45, 0.1, 0.3), gripper_open=True)
        assert (refused.status, refused.reason) == ("failed", "control_error")
        assert re.search(r"error code -1\d\d\b", refused.detail), refused.detail
        assert arm.counters["replans"] == 1
    finally:
        arm.disconnect()


def test_pose_outside_the_workspace_is_refused_without_motion(arm, sim):
    before = sim.joint_positions()
    for target, reason in [((1.2, 0.0, 0.3), "out_of_workspace"), ((0.5, 0.0, -0.05), "below_table"),
                           ((0.5, 0.0, float("nan")), "invalid_action")]:
        result = arm.move_to(pose(*target), gripper_open=True)
        assert (result.status, result.reason) == ("refused", reason)
    time.sleep(0.2)
    assert np.abs(sim.joint_positions() - before).max() < 1e-3  # the arm never moved
    assert arm.safety.counters() == {"refused_out_of_workspace": 1, "refused_below_table": 1,
                                     "refused_invalid_action": 1}
    assert arm.counters["moves"] == 0


def test_stop_during_a_move_halts_it_and_latches(arm, sim):
    start = sim.joint_positions()
    results = []
    mover = threading.Thread(target=lambda: results.append(arm.move_to(pose(0.6, -0.25, 0.35), gripper_open=True)))
    mover.start()
    deadline = time.monotonic() + 30
    while np.abs(sim.joint_positions() - start).max() < 0.01 and time.monotonic() < deadline:
        time.sleep(0.005)  # stop as soon as the arm is under way: ~30 cm of the move still ahead
    stop_to_still = arm.stop()
    mover.join(timeout=30)
    assert results and (results[0].status, results[0].reason) == ("failed", "stopped")
    assert stop_to_still < 3.0  # measured ~0.3 s of simulated time; generous for a busy machine
    halted = sim.joint_positions()
    time.sleep(0.3)
    assert np.abs(sim.joint_positions() - halted).max() < 2e-3  # it stays where it stopped
    assert np.linalg.norm(arm.grasp_pose()[:3] - [0.6, -0.25, 0.35]) > 0.02  # short of the target
    assert arm.move_to(pose(0.45, 0.0, 0.3), gripper_open=True).reason == "stopped"  # latched
    arm.resume()
    assert arm.move_to(pose(0.45, 0.0, 0.3), gripper_open=True).reached


def test_lost_connection_is_recovered_and_the_next_move_works(arm, sim):
    results = []
    mover = threading.Thread(target=lambda: results.append(arm.move_to(pose(0.6, -0.2, 0.4), gripper_open=True)))
    mover.start()
    time.sleep(0.3)
    sim.pause(1.5)  # no robot state for 1.5 s: libfranka's UDP receive times out, as on a network drop
    mover.join(timeout=30)
    assert results and (results[0].status, results[0].reason) == ("failed", "connection_lost"), results
    assert arm.recover()
    assert arm.counters["reconnects"] == 1
    result = arm.move_to(pose(0.45, 0.1, 0.3), gripper_open=True)
    assert result.reached, result


def test_a_twisted_arm_unwinds_in_joint_space_and_goes_home_again(arm):
    """Where a wild pose left the wrist (here turned near its limit), the robot env's reset unwinds, then moves home."""
    import franky

    twisted = np.array(arm.config.home_joints)
    twisted[6] = 2.6  # the wrist turned ~105 degrees past its home
    arm._robot.move(franky.JointMotion(twisted))
    assert np.abs(arm.joint_positions() - twisted).max() < 0.05

    assert arm.unwind() and arm.counters["unwinds"] == 1
    assert np.abs(arm.joint_positions() - np.array(arm.config.home_joints)).max() < 0.05
    assert arm.move_to(pose(0.45, 0.0, 0.4), gripper_open=True).reached
