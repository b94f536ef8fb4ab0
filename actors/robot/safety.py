"""Safety limits checked before a pose is sent: a workspace box, the table, a longest step.

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
        return None

    def counters(self) -> dict[str, int]:
        """Refusals so far, one ``refused_<reason>`` key per reason seen."""
        return {f"refused_{reason}": n for reason, n in self.refused.items()}
