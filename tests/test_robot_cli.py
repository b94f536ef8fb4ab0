"""`c2farm robot` / `c2farm launch --robot ...`: the flags become the typed robot config."""

from __future__ import annotations

import pytest

from deploy.cli import build_parser, overrides_from_args, with_robot_role
from deploy.config import DEFAULT_ROLES, load_config
from deploy.config_loader import ConfigError


def resolve(*argv: str, preset=None):
    args = build_parser(demo_options=False).parse_args(list(argv))
    config = load_config(preset=preset, overrides=tuple(overrides_from_args(args)))
    with_robot_role(args, config)
    return config


def test_launch_with_a_robot_adds_the_robot_role():
    config = resolve("launch", "--robot", "franky-sim", "--camera", "mujoco")
    assert config.launch.roles == [*DEFAULT_ROLES, "robot"]
    assert config.robot.arm == "franky-sim"
    assert [(c.name, c.kind) for c in config.robot.cameras] == [("front", "mujoco")]


def test_the_robot_preset_keeps_its_roles_and_takes_three_demos():
    config = resolve("launch", "--robot", "franka", "--robot-host", "172.16.0.2", preset="robot")
    assert config.launch.roles == ["router", "replay", "dashboard", "learner", "demo_source", "robot"]
    assert config.demos.episodes == 3


def test_a_plain_launch_starts_no_robot():
    assert "robot" not in resolve("launch").launch.roles


def test_robot_flags_name_the_arm_and_the_cameras():
    config = resolve("robot", "--run-id", "r1", "--robot", "franka", "--robot-host", "172.16.0.2",
                     "--camera", "realsense:123", "--camera", "realsense:456")
    assert config.robot.franka.host == "172.16.0.2"
    assert [(c.name, c.kind, c.serial) for c in config.robot.cameras] == [
        ("front", "realsense", "123"), ("left_shoulder", "realsense", "456")]


def test_a_scripted_operator_needs_the_simulated_arm():
    with pytest.raises(ConfigError, match="scripted_operator"):
        resolve("robot", "--run-id", "r1", "--robot", "franka", "--set", "robot.scripted_operator=true")


def test_a_bad_waypoints_file_is_one_line_before_the_arm_moves(tmp_path, capsys):
    from deploy.cli import main

    waypoints = tmp_path / "task.txt"
    waypoints.write_text("0.5 0.1 0.3 open via\n0.5 0.1 sideways close\n")
    # The host is one no arm answers on: the refusal has to come before any connection.
    code = main(["robot-demos", "--robot", "franka", "--robot-host", "192.0.2.1", "--waypoints", str(waypoints),
                 "--set", f"demos.directory={tmp_path / 'demos'}"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "0.5 0.1 sideways close" in err and "Traceback" not in err


def test_a_mistyped_waypoint_is_typed_again(monkeypatch, capsys):
    import io

    from deploy.robot_demos import typed_waypoints

    monkeypatch.setattr("sys.stdin", io.StringIO("0.5 0.1 0.3 open via\n0.5 0.1 close\n0.5 0.1 0.15 close\n\n"))
    waypoints = typed_waypoints()
    assert [(list(w.pose[:3]), w.gripper_open, w.keyframe) for w in waypoints] == [
        ([0.5, 0.1, 0.3], True, False), ([0.5, 0.1, 0.15], False, True)]
    assert "type it again" in capsys.readouterr().out


def test_more_cameras_than_an_observation_holds_is_an_error_not_a_silent_drop():
    with pytest.raises(ConfigError, match="at most 4 cameras"):
        resolve(
            "robot",
            "--run-id",
            "r1",
            "--robot",
            "franka",
            *[w for s in "12345" for w in ("--camera", f"realsense:{s}")],
        )


def test_the_robot_preset_falls_back_to_poses_the_safety_limits_allow():
    config = resolve("launch", "--robot", "franka", "--robot-host", "172.16.0.2", preset="robot")
    assert config.actor.reachable_top_k == 8


def test_foxglove_serves_the_robot_actors_scene_on_8765_or_the_port_given():
    assert resolve("robot", "--run-id", "r1", "--robot", "franky-sim", "--foxglove").actor.foxglove_port == 8765
    assert resolve("robot", "--run-id", "r1", "--foxglove", "9000").actor.foxglove_port == 9000
    assert resolve("robot", "--run-id", "r1").actor.foxglove_port == -1  # off unless asked
