"""Time parameterisation with Ruckig under the Panda's velocity/acceleration/jerk limits.

The arm must move along the very path the planner checked for collisions, so we run 1-DoF Ruckig
along the path's arc length, with limits scaled so no joint exceeds its own, and map it back onto
the path. This holds for a single straight segment too: a time-synchronised 7-DoF Ruckig segment
reaches the goal with every joint at once, but on its own velocity profile, so the joint-space
path bows away from the checked line (pick_and_lift: open fingers, planned to clear the block by
1 cm, swept into it). Several vertices (an OMPL path): the community Ruckig cannot pass through
waypoints (intermediate_positions is a Pro feature that tries a cloud API); along the arc length the
arm does not stop at every vertex either, which would read as spurious "stopped" keyframes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from actors.control.limits import MAX_ACCELERATION, MAX_JERK, MAX_VELOCITY


@dataclass
class JointTrajectory:
    """q(t), qd(t) for t in [0, duration]."""

    ruckig: Trajectory
    path: np.ndarray  #: the vertices [N, 7]
    cumulative: np.ndarray  #: arc length at each vertex

    @property
    def duration(self) -> float:
        return float(self.ruckig.duration)

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        pos, vel, _ = self.ruckig.at_time(min(max(t, 0.0), self.duration))
        s, sd = pos[0], vel[0]
        k = int(np.clip(np.searchsorted(self.cumulative, s, side="right") - 1, 0, len(self.path) - 2))
        seg = self.path[k + 1] - self.path[k]
        length = self.cumulative[k + 1] - self.cumulative[k]
        u = seg / length if length > 0 else np.zeros(7)
        return self.path[k] + u * (s - self.cumulative[k]), u * sd


def _along_path(length: float, vmax: float, amax: float, jmax: float) -> Trajectory:
    """Time-optimal 1-DoF Ruckig profile from rest at arc length 0 to rest at ``length``."""
    inp = InputParameter(1)
    inp.current_position, inp.target_position = [0.0], [float(length)]
    inp.current_velocity = inp.current_acceleration = [0.0]
    inp.target_velocity = inp.target_acceleration = [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [float(vmax)], [float(amax)], list(jerk_floor([jmax]))
    traj = Trajectory(1)
    result = Ruckig(1).calculate(inp, traj)
    if result not in (Result.Working, Result.Finished):
        raise RuntimeError(f"Ruckig failed: {result}")
    return traj


def jerk_floor(j):
    return np.maximum(np.asarray(j, dtype=float), 1e-6)


def parameterise(path: np.ndarray, velocity_scale: float = 0.5, acceleration_scale: float = 0.5) -> JointTrajectory:
    """Time-optimal trajectory along ``path`` [N >= 2, 7] (exactly on it), at rest at both ends."""
    vmax = MAX_VELOCITY * velocity_scale
    amax, jmax = MAX_ACCELERATION * acceleration_scale, MAX_JERK * acceleration_scale
    path = np.asarray(path, dtype=float)
    lengths = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    # the steepest joint per unit arc length bounds the path speed
    slope = np.max(np.abs(np.diff(path, axis=0)) / np.maximum(lengths[:, None], 1e-12), axis=0)
    slope = np.maximum(slope, 1e-9)
    traj = _along_path(cumulative[-1], np.min(vmax / slope), np.min(amax / slope), np.min(jmax / slope))
    return JointTrajectory(traj, path, cumulative)
