"""Demos recorded on the robot are the simulator's demo files: the demo source sends them unchanged,
learning from the keyframes the operator marked (every waypoint's end but a via-point's)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from actors.robot.demos import parse_waypoint, read_waypoints


def test_waypoint_lines():
    wp = parse_waypoint("0.5 0.0 0.2 close  # grasp")
    assert np.allclose(wp.pose, [0.5, 0.0, 0.2, 1, 0, 0, 0]) and not wp.gripper_open and wp.keyframe
    assert parse_waypoint("0.5 0 0.2 0 1 0 0 open").gripper_open
    assert parse_waypoint("   # nothing") is None
    via = parse_waypoint("0.4 0.2 0.3 open via  # around the box")
    assert np.allclose(via.pose[:3], [0.4, 0.2, 0.3]) and via.gripper_open and not via.keyframe


@pytest.mark.parametrize("line", ["0.5 0.2 open", "0.5 0 0.2 shut", "0.5 zero 0.2 open", "0.5 0 nan close",
                                  "0.5 0 0.2 via open", "via", "0.5 0 0.2 open via via"])
def test_a_bad_waypoint_line_is_one_line_naming_it(line):
    with pytest.raises(ValueError, match="expected 'x y z") as err:
        parse_waypoint(line)
    assert repr(line) in str(err.value) and "\n" not in str(err.value)


def test_the_last_waypoint_cannot_be_a_via_point():
    with pytest.raises(ValueError, match="last waypoint"):
        read_waypoints(["0.5 0.1 0.3 open", "0.5 0.1 0.15 close via"])


@pytest.fixture(scope="module")
def robot_demo():
    """A demo recorded on franky-sim: over the target (a via-point), then down to it and close."""
    pytest.importorskip("franky")
    pytest.importorskip("franky_sim")
    from actors.robot.config import FrankaConfig, SafetyConfig
    from actors.robot.demos import record_robot_demo
    from actors.robot.franka import FrankaArm
    from actors.robot.franky_sim import FrankySim

    with FrankySim() as sim:
        sim.set_target((0.5, 0.1, 0.15))
        arm = FrankaArm(FrankaConfig(host=sim.hostname, dynamics_factor=0.3), SafetyConfig(), [sim.camera("front")])
        arm.connect()
        try:
            waypoints = read_waypoints(["0.5 0.1 0.3 open via", "0.5 0.1 0.15 close"])
            demo = record_robot_demo(arm, waypoints, "reach_target", seed=0, hz=10)
        finally:
            arm.disconnect()
    assert demo.success and len(demo.waypoint_frames) == 2 and len(demo.observations) > 4
    return demo


def _first_episode_targets(path) -> np.ndarray:
    """Where the demo source's episode from frame 0 jumps: one row (pose + gripper) per keyframe."""
    from actors.demo_source import demo_episodes

    episodes = demo_episodes(path, 0, "demos")
    assert episodes and all(e.is_demo for e in episodes)
    return episodes[0].actions


def test_a_robot_demo_loads_in_the_demo_source_with_the_operators_keyframes(robot_demo, tmp_path):
    from actors.demos.augmentation import keyframe_action
    from protocol.episode_file import load_demo, write_demo

    assert robot_demo.keyframes == robot_demo.waypoint_frames[1:]  # the via-point's end is no keyframe
    path = tmp_path / "robot-demo-0.mcap"
    write_demo(path, robot_demo)
    loaded = load_demo(path)
    assert loaded.keyframes == robot_demo.keyframes and loaded.waypoint_frames == robot_demo.waypoint_frames
    targets = _first_episode_targets(path)
    assert np.array_equal(targets, [keyframe_action(loaded.observations[k]) for k in robot_demo.keyframes])
    assert np.linalg.norm(targets[-1][:3] - [0.5, 0.1, 0.15]) < 0.01 and targets[-1][7] == 0.0  # closed at the target


def test_a_robot_demo_without_operator_keyframes_loads_through_discovery(robot_demo, tmp_path):
    """Files recorded before operator keyframes: the reference rule, which also stops at the via-point."""
    from actors.demos.augmentation import keyframe_action
    from actors.demos.keyframes import discover_keyframes
    from protocol.episode_file import load_demo, write_demo

    path = tmp_path / "robot-demo-old.mcap"
    write_demo(path, dataclasses.replace(robot_demo, keyframes=None))
    loaded = load_demo(path)
    assert loaded.keyframes is None
    keyframes = discover_keyframes(loaded.observations)
    # The reference rule stops where every waypoint ends, the via-point's too. Judged by where the arm
    # stands, not by frame: it fires once the arm is nearly still, a frame or more before the recorder
    # has waited out the settling (how many depends on the machine's load).
    stops = np.array([loaded.observations[k].gripper_pose[:3] for k in keyframes])
    for waypoint in ((0.5, 0.1, 0.3), (0.5, 0.1, 0.15)):
        nearest = np.linalg.norm(stops - waypoint, axis=1).min()
        assert nearest < 0.01, (waypoint, keyframes, stops.round(3).tolist())
    targets = _first_episode_targets(path)
    assert np.array_equal(targets, [keyframe_action(loaded.observations[k]) for k in keyframes])
