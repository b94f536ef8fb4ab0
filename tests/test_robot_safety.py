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
