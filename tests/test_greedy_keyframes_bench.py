"""bench/greedy_keyframes.py: each greedy pose named after the scripted keyframe it went for, read off the
evaluator's recorded episodes and the scene rebuilt from each episode's seed."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pybullet

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import greedy_keyframes  # noqa: E402  (bench/greedy_keyframes.py)

from protocol.episode_file import write_episode_mcap  # noqa: E402
from protocol.observation import Observation  # noqa: E402


def _frame() -> Observation:
    return Observation(cameras={}, gripper_pose=np.array([0.3, 0, 0.5, 1, 0, 0, 0], np.float32), gripper_open=1.0,
                       finger_positions=np.zeros(2, np.float32), joint_positions=np.zeros(7, np.float32),
                       joint_velocities=np.zeros(7, np.float32))


def test_an_episode_reads_as_the_keyframes_it_went_for_and_where_it_stopped(tmp_path):
    (tmp_path / "eval").mkdir()
    seed = 1_000_003
    scripted = greedy_keyframes.scene_keyframes("open_drawer", [seed])[seed]  # approach, grasp, pull
    assert scripted.shape == (3, 8) and scripted[0, 7] == 1.0 and scripted[1, 7] == 0.0
    too_deep = scripted[1].copy()
    too_deep[:3] += greedy_keyframes.quaternion_matrix(too_deep[3:7])[:, 2] * 0.05  # 5 cm along the hand's approach
    write_episode_mcap(tmp_path / "eval" / f"v000010-seed{seed}.mcap", [_frame()] * 3, "open_drawer", seed, False,
                       actions=[scripted[0], too_deep], end_reason="unreachable", unreachable_reason="ik_failed")
    write_episode_mcap(tmp_path / "eval" / f"v000004-seed{seed}.mcap", [_frame()] * 2, "open_drawer", seed, False,
                       actions=[scripted[2]], end_reason="unreachable", unreachable_reason="ik_failed")

    episodes = greedy_keyframes.read_episodes(tmp_path, from_version=5)  # version 4 left out
    sequences, near = greedy_keyframes.by_keyframe(episodes)
    assert sequences == {("unreachable", "k1o k2c"): 1}
    assert len(near[0]["went on"]) == 1 and np.allclose(near[0]["went on"][0], 0, atol=1e-3)
    (x, y, z, rotation), = near[1]["stopped"]
    assert abs(x) < 1e-3 and abs(y) < 1e-3 and abs(z - 5.0) < 1e-3 and rotation < 0.1


def test_a_half_turn_about_the_approach_is_the_same_grasp():
    down = np.array(pybullet.getQuaternionFromEuler((np.pi, 0, 0.3)))
    turned = np.array(pybullet.getQuaternionFromEuler((np.pi, 0, 0.3 + np.pi)))
    tilted = np.array(pybullet.getQuaternionFromEuler((np.pi, 0, 0.5)))
    assert greedy_keyframes.rotation_deg(down, turned) < 1e-3
    assert abs(greedy_keyframes.rotation_deg(down, tilted) - np.degrees(0.2)) < 1e-3
