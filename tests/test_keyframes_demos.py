"""Keyframe discovery (ARM's rule, the authors' keypoint_discovery) recovers every task's scripted waypoints exactly;
a demo with its operator's keyframes keeps those."""

import numpy as np
import pytest

from actors.demos import Demo, demo_to_transitions, discover_keyframes, load_demo, write_demo
from actors.demos.generate import record_demo
from actors.demos.keyframes import demo_keyframes
from actors.panda_env import PandaEnv
from actors.sim import TASKS, SimConfig
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


def _jittery_demo(keyframes=None) -> Demo:
    """The arm pauses at 3 on its way (a jitter the rule takes for a stop), closes the gripper at 7, ends at 10."""
    flags = [(1, 0), (1, 1), (1, 1), (1, 0), (1, 1), (1, 1), (1, 1), (0, 0), (0, 1), (0, 1), (0, 1)]
    observations = [_obs(float(g), bool(m)) for g, m in flags]
    for i, o in enumerate(observations):
        o.gripper_pose = np.array([0.1 * i, 0, 0, 0, 0, 0, 1], np.float32)
    return Demo("reach_target", 0, True, observations, waypoint_frames=[7, 10], keyframes=keyframes)


def test_operator_keyframes_replace_discovery_and_drive_augmentation():
    assert demo_keyframes(_jittery_demo()) == [3, 7, 10]  # no operator keyframes: the rule, pause included
    demo = _jittery_demo(keyframes=[7, 10])
    assert demo_keyframes(demo) == [7, 10]
    episodes = demo_to_transitions(demo.observations, demo_keyframes(demo), every_n=4)  # from frames 0, 4, 8
    assert [len(e.actions) for e in episodes] == [2, 2, 1]
    assert np.allclose(episodes[0].actions[:, 0], [0.7, 1.0]) and episodes[0].rewards.tolist() == [0.0, 100.0]


def test_cut_chains_store_each_keyframe_jump_once_and_leave_the_rest_to_frame_zeros_chain():
    observations = _jittery_demo().observations  # keyframes 3, 7, 10; episodes from frames 0, 2, 4, 6, 8
    full = demo_to_transitions(observations, [3, 7, 10], every_n=2)
    assert [len(e.actions) for e in full] == [3, 3, 2, 2, 1]  # the authors': every chain runs to the end
    cut = demo_to_transitions(observations, [3, 7, 10], every_n=2, chain_keyframes=1)
    assert [len(e.actions) for e in cut] == [3, 1, 1, 1, 1]
    assert cut[0].rewards.tolist() == [0.0, 0.0, 100.0] and cut[0].terminals.tolist() == [False, False, True]
    # a cut chain ends unfinished: no reward, no terminal, so the learner bootstraps from the keyframe it reaches
    assert cut[1].rewards.tolist() == [0.0] and not cut[1].terminals[0]
    assert np.allclose(cut[1].actions[:, 0], [0.3]) and np.allclose(cut[2].actions[:, 0], [0.7])
    assert cut[4].rewards.tolist() == [100.0] and cut[4].terminals[0]  # its one jump ends the demo: finished
    # the first keyframe's share of the stored jumps: 2 of 11 in full chains, 2 of 7 cut
    targets = [[a[0] for a in e.actions] for e in cut]
    assert sum(t.count(np.float32(0.3)) for t in targets) == 2 and sum(map(len, targets)) == 7


def test_the_demo_source_learns_from_the_operators_keyframes_else_discovers_them(tmp_path):
    from actors.demo_source import demo_episodes

    marked, unmarked = tmp_path / "marked.mcap", tmp_path / "unmarked.mcap"
    write_demo(marked, _jittery_demo(keyframes=[7, 10]))
    write_demo(unmarked, _jittery_demo())  # as every file written before operator keyframes
    assert load_demo(marked).keyframes == [7, 10] and load_demo(unmarked).keyframes is None
    first_jumps = {path.stem: demo_episodes(path, 0, "demos")[0].actions[:, 0] for path in (marked, unmarked)}
    assert np.allclose(first_jumps["marked"], [0.7, 1.0])  # x of the gripper at frames 7 and 10
    assert np.allclose(first_jumps["unmarked"], [0.3, 0.7, 1.0])  # discovery also stops at the pause


def test_demos_carry_the_box_they_were_recorded_for_when_a_robot_is_in_the_run(tmp_path):
    """A robot's episodes carry its own depth-0 box; demos then carry theirs, so the replay sees one set of arrays."""
    from actors.demo_source import demo_episodes, task_bounds

    robot_box = (0.2, -0.4, 0.0, 0.75, 0.4, 0.6)
    simulated, robot = tmp_path / "sim.mcap", tmp_path / "robot.mcap"
    write_demo(simulated, _jittery_demo())
    demo = _jittery_demo(keyframes=[7, 10])
    demo.scene_bounds = robot_box
    write_demo(robot, demo)
    assert load_demo(robot).scene_bounds == robot_box and load_demo(simulated).scene_bounds is None

    def boxes(path, on=True):
        return {tuple(e.observations.get("extra_scene_bounds", np.zeros((1, 0)))[0].round(4))
                for e in demo_episodes(path, 0, "demos", scene_bounds_on_wire=on)}

    assert boxes(robot) == {tuple(np.float32(robot_box).round(4))}
    assert boxes(simulated) == {tuple(np.float32(task_bounds("reach_target")).round(4))}
    assert boxes(simulated, on=False) == {()}  # a simulated run's demos are sent as before


def test_bad_operator_keyframes_are_refused(tmp_path):
    with pytest.raises(ValueError, match="increasing"):
        write_demo(tmp_path / "bad.mcap", _jittery_demo(keyframes=[10, 7]))


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
