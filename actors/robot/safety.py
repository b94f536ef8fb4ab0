"""Safety limits checked before a pose is sent: a workspace box, the table, a longest step, the wrist's range.

The orientation limits matter as much as the box: the policy picks any of 72^3 Euler bins, and a
straight Cartesian move to a gripper pointing up or a wrist turned past its joint limit stops
part-way, leaving the arm twisted where the next moves fail too.

A refused pose is counted per reason and never reaches the arm. The same checks apply to every
arm, so they live here rather than in an arm's driver.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from actors.robot.config import SafetyConfig


class Safety:
    """Refuses poses outside the configured limits and counts why."""

    def __init__(self, config: SafetyConfig) -> None:
        self.config = config
        self.lo = np.asarray(config.workspace_min, dtype=float)
        self.hi = np.asarray(config.workspace_max, dtype=float)
        self.refused: Counter[str] = Counter()

    def check(self, pose: np.ndarray, current_position: np.ndarray) -> str | None:
        """None when ``pose`` (xyz + quaternion) may be sent from ``current_position``, else why not (counted)."""
        reason = self._why_not(np.asarray(pose, dtype=float), np.asarray(current_position, dtype=float))
        if reason is not None:
            self.refused[reason] += 1
        return reason

    def allows(self, pose: np.ndarray, current_position: np.ndarray) -> bool:
        """Whether ``check`` would pass, without counting (reachability tests while acting)."""
        return self._why_not(np.asarray(pose, dtype=float), np.asarray(current_position, dtype=float)) is None

    def _why_not(self, pose: np.ndarray, current: np.ndarray) -> str | None:
        if pose.shape != (7,) or not np.all(np.isfinite(pose)) or np.linalg.norm(pose[3:]) < 1e-6:
            return "invalid_action"
        position = pose[:3]
        if position[2] < self.config.table_height + self.config.table_clearance:
            return "below_table"
        if np.any(position < self.lo) or np.any(position > self.hi):
            return "out_of_workspace"
        if np.linalg.norm(position - current) > self.config.max_step:
            return "step_too_far"
        tilt, yaw = tilt_and_yaw(pose[3:])
        if tilt > self.config.max_tilt_deg:
            return "tilted"
        if abs(yaw) > self.config.max_yaw_deg:
            return "wrist_turned"
        return None

    def counters(self) -> dict[str, int]:
        """Refusals so far, one ``refused_<reason>`` key per reason seen."""
        return {f"refused_{reason}": n for reason, n in self.refused.items()}


def tilt_and_yaw(quaternion_xyzw) -> tuple[float, float]:
    """(degrees of the approach axis from straight down, signed degrees about the vertical).

    The yaw is that of the gripper's x axis projected on the table, from the top-down frame
    (quaternion 1 0 0 0: x along the world's x, fingers along y, approach straight down).
    """
    x, y, z, w = np.asarray(quaternion_xyzw, dtype=float) / np.linalg.norm(quaternion_xyzw)
    approach_z = 1 - 2 * (x * x + y * y)  # world z of the frame's z axis
    x_axis = (1 - 2 * (y * y + z * z), 2 * (x * y + w * z))  # world x, y of the frame's x axis
    tilt = float(np.degrees(np.arccos(np.clip(-approach_z, -1.0, 1.0))))
    yaw = float(np.degrees(np.arctan2(x_axis[1], x_axis[0]))) if np.hypot(*x_axis) > 1e-6 else 0.0
    return tilt, yaw
