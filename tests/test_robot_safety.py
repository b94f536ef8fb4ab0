"""Safety limits refuse a pose before any arm sees it, and count why."""

from __future__ import annotations

import numpy as np
import pytest

from actors.robot.config import SafetyConfig
from actors.robot.safety import Safety

DOWN = [1.0, 0.0, 0.0, 0.0]


@pytest.fixture
def safety():
    return Safety(SafetyConfig(workspace_min=(0.2, -0.4, 0.0), workspace_max=(0.75, 0.4, 0.6),
                               table_height=0.02, table_clearance=0.01, max_step=0.3))


@pytest.mark.parametrize("position, reason", [
    ((0.5, 0.0, 0.3), None),
    ((0.8, 0.0, 0.3), "out_of_workspace"),
    ((0.5, 0.5, 0.3), "out_of_workspace"),
    ((0.5, 0.0, 0.025), "below_table"),  # above z = 0 but within the clearance of a 2 cm table
    ((0.25, 0.35, 0.55), "step_too_far"),  # inside the box, 0.52 m from the gripper
])
def test_each_limit_has_its_reason(safety, position, reason):
    assert safety.check(np.array([*position, *DOWN]), np.array([0.5, 0.0, 0.3])) == reason


def test_malformed_poses_are_invalid(safety):
    here = np.array([0.5, 0.0, 0.3])
    assert safety.check(np.array([0.5, 0.0, np.inf, *DOWN]), here) == "invalid_action"
    assert safety.check(np.array([0.5, 0.0, 0.3, 0, 0, 0, 0]), here) == "invalid_action"
    assert safety.check(np.array([0.5, 0.0, 0.3]), here) == "invalid_action"


def test_refusals_are_counted_per_reason(safety):
    here = np.array([0.5, 0.0, 0.3])
    for position in [(0.9, 0, 0.3), (0.9, 0, 0.3), (0.5, 0, 0.0)]:
        safety.check(np.array([*position, *DOWN]), here)
    assert safety.counters() == {"refused_out_of_workspace": 2, "refused_below_table": 1}


def test_an_inverted_box_is_a_config_error():
    with pytest.raises(ValueError, match="below"):
        SafetyConfig(workspace_min=(0.5, 0, 0), workspace_max=(0.4, 1, 1))


def _product(a, b):
    """Hamilton product of two xyzw quaternions: rotate by b, then by a."""
    (ax, ay, az, aw), (bx, by, bz, bw) = a, b
    return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


def turned(tilt_about_y_deg: float = 0.0, yaw_deg: float = 0.0) -> list[float]:
    """Top-down, turned ``yaw_deg`` about the vertical, then tipped ``tilt_about_y_deg`` about the world y axis."""
    half_tilt, half_yaw = np.radians(tilt_about_y_deg) / 2, np.radians(yaw_deg) / 2
    tilt = [0.0, np.sin(half_tilt), 0.0, np.cos(half_tilt)]
    yaw = [0.0, 0.0, np.sin(half_yaw), np.cos(half_yaw)]
    return _product(tilt, _product(yaw, DOWN))


@pytest.mark.parametrize("quaternion, reason", [
    (turned(), None),
    (turned(tilt_about_y_deg=45, yaw_deg=-100), None),
    (turned(tilt_about_y_deg=75), "tilted"),  # the config allows 60 degrees from straight down
    ([0.0, 0.0, 0.0, 1.0], "tilted"),  # the gripper pointing up
    (turned(yaw_deg=150), "wrist_turned"),  # past the 120 degrees the wrist is allowed from the top-down frame
    (turned(yaw_deg=-150), "wrist_turned"),
])
def test_the_gripper_orientation_stays_in_the_wrists_range(safety, quaternion, reason):
    """An untrained policy picks any of 72^3 rotations; a flipped or over-turned wrist never reaches the arm."""
    assert safety.check(np.array([0.5, 0.0, 0.3, *quaternion]), np.array([0.5, 0.0, 0.3])) == reason
