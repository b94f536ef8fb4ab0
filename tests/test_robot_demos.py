"""Demos recorded on the robot are the simulator's demo files: the demo source sends them unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from actors.robot.demos import parse_waypoint


def test_waypoint_lines():
    wp = parse_waypoint("0.5 0.0 0.2 close  # grasp")
    assert np.allclose(wp.pose, [0.5, 0.0, 0.2, 1, 0, 0, 0]) and not wp.gripper_open
    assert parse_waypoint("0.5 0 0.2 0 1 0 0 open").gripper_open
    assert parse_waypoint("   # nothing") is None
    with pytest.raises(ValueError, match="expected"):
        parse_waypoint("0.5 0.2 open")


def test_a_robot_demo_loads_in_the_demo_source_like_a_simulated_one(tmp_path):
    pytest.importorskip("franky")
    pytest.importorskip("franky_sim")
    from actors.demo_source import demo_episodes
    from actors.demos.keyframes import discover_keyframes
    from actors.demos.mcap_io import load_demo, write_demo
    from actors.robot.config import FrankaConfig, SafetyConfig
    from actors.robot.demos import record_robot_demo
    from actors.robot.franka import FrankaArm
    from actors.robot.franky_sim import FrankySim

    with FrankySim() as sim:
        sim.set_target((0.5, 0.1, 0.15))
        arm = FrankaArm(FrankaConfig(host=sim.hostname, dynamics_factor=0.3), SafetyConfig(), [sim.camera("front")])
        arm.connect()
        try:
            waypoints = [parse_waypoint("0.5 0.1 0.3 open"), parse_waypoint("0.5 0.1 0.15 close")]
            demo = record_robot_demo(arm, waypoints, "reach_target", seed=0, hz=10)
        finally:
            arm.disconnect()
    assert demo.success and len(demo.waypoint_frames) == 2 and len(demo.observations) > 4
    path = tmp_path / "robot-demo-0.mcap"
    write_demo(path, demo)
    loaded = load_demo(path)
    assert loaded.waypoint_frames == demo.waypoint_frames
    keyframes = discover_keyframes(loaded.observations)
    print("waypoint ends", demo.waypoint_frames, "keyframes", keyframes, "frames", len(demo.observations))
    for end in demo.waypoint_frames:  # the reference rule finds where the operator's waypoints end
        assert any(abs(k - end) <= 1 for k in keyframes), (end, keyframes)
    episodes = demo_episodes(path, 0, "demos")
    assert episodes and all(e.is_demo for e in episodes)
    final = episodes[0].actions[-1]
    assert np.linalg.norm(final[:3] - [0.5, 0.1, 0.15]) < 0.01 and final[7] == 0.0  # the last keyframe: closed at the target
