"""Keyframe discovery (ARM's rule, c2farm_spec 6.1) recovers every task's scripted waypoints exactly."""

import numpy as np
import pytest

from actors.demos import discover_keyframes
from actors.demos.generate import record_demo
from actors.sim import TASKS, PandaEnv, SimConfig
from protocol.observation import Observation


def _obs(gripper_open, moving):
    return Observation(cameras={}, gripper_pose=np.zeros(7, np.float32), gripper_open=gripper_open,
                       finger_positions=np.zeros(2, np.float32), joint_positions=np.zeros(7, np.float32),
                       joint_velocities=np.full(7, 0.5 if moving else 0.0, np.float32))


def test_reference_rule_on_a_hand_made_demo():
    # moving, stop at 3, moving, gripper closes at 7, moving, end
    flags = [(1, 0), (1, 1), (1, 1), (1, 0), (1, 1), (1, 1), (1, 1), (0, 0), (0, 1), (0, 1), (0, 1)]
    demo = [_obs(float(g), bool(m)) for g, m in flags]
    assert discover_keyframes(demo) == [3, 7, 10]


def test_last_two_consecutive_keyframes_keep_the_last():
    demo = [_obs(1.0, True)] * 5 + [_obs(0.0, True)] + [_obs(0.0, True)]
    assert discover_keyframes(demo) == [6]


@pytest.mark.parametrize("task", TASKS)
def test_keyframes_recover_the_scripted_waypoints(task):
    env = PandaEnv(SimConfig(task=task, cameras=()))
    for seed in range(21, 26):  # as the demo generator does, a failed scripted demo moves on to the next seed
        env.reset(seed)
        waypoints = env.demo_waypoints()  # where the objects are before the demo moves them
        demo = record_demo(env, seed=seed)
        if demo.success:
            break
    env.close()
    assert demo.success
    keyframes = discover_keyframes(demo.observations)
    assert keyframes == demo.waypoint_frames
    for k, wp in zip(keyframes, waypoints):
        obs = demo.observations[k]
        assert np.linalg.norm(obs.gripper_pose[:3] - wp.position) < 0.01
        assert obs.gripper_open == wp.gripper_open
