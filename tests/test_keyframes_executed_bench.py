"""bench/keyframes_executed.py: a task's demo keyframes, snapped to what the cascade can say, executed again."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("bench_keyframes_executed", REPO / "bench" / "keyframes_executed.py")
keyframes_executed = importlib.util.module_from_spec(_spec)
sys.modules["bench_keyframes_executed"] = keyframes_executed
_spec.loader.exec_module(keyframes_executed)


def test_snapping_lands_on_voxel_centres_and_rotation_bins():
    from qattention import QAttentionConfig

    config = QAttentionConfig(scene_bounds=(0.0, 0.0, 0.0, 1.0, 1.0, 1.0))
    pose = np.array([[0.501, 0.25, 0.7, 0.0, 0.0, np.sin(0.06), np.cos(0.06), 1.0]])  # yaw 6.9 degrees
    snapped = keyframes_executed.snap(pose, config)
    assert np.abs(snapped[0, :3] - pose[0, :3]).max() <= 0.3 / 16 / 2 + 1e-6  # within half a last-depth voxel
    yaw = np.degrees(2 * np.arctan2(snapped[0, 5], snapped[0, 6]))
    assert abs(yaw - 5.0) < 1e-3 and snapped[0, 7] == 1.0  # the nearest 5-degree bin, gripper kept
    approach_then_grasp = np.array([[0, 0, 0.2, 0, 0, 0, 1, 1.0], [0, 0, 0.1, 0, 0, 0, 1, 0.0]])
    assert len(keyframes_executed.direct(approach_then_grasp)) == 1
    assert len(keyframes_executed.direct(approach_then_grasp[::-1])) == 2  # the first one closes: not an approach


def test_a_task_the_arm_can_do_succeeds_in_every_variant(capsys):
    assert keyframes_executed.main(["--tasks", "reach_target", "--episodes", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("## reach_target: 2 evaluation seeds, grid 3 x 8^3")  # the preset's (8,8,8)
    for variant in keyframes_executed.VARIANTS:
        assert next(line for line in lines if line.split()[0] == variant).split()[1:] == ["2", "success"]
