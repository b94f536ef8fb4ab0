"""The robot interface: what the robot actor needs from an arm, whichever arm it is.

An arm turns a next-best pose into motion and reports an outcome, never an exception: a pose
the safety limits refuse never reaches the arm ("refused"), a motion the arm could not finish
("failed") ends the episode like an unreachable pose does in the simulator. ``stop()`` halts
the arm at once from any thread and latches: every move is refused until ``resume()``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from protocol.observation import Observation

MoveStatus = Literal["reached", "refused", "failed"]

#: Why a move was refused before any motion: bad numbers, the safety limits, an operator stop.
REFUSAL_REASONS = ("invalid_action", "out_of_workspace", "below_table", "step_too_far", "stopped")
#: Why a started move failed: the operator stopped it, the arm reported an error, the
#: connection dropped, it timed out, or it ended too far from the target.
FAILURE_REASONS = ("stopped", "control_error", "connection_lost", "timeout", "not_reached", "gripper_failed")


@dataclass
class MoveResult:
    """What became of one next-best pose."""

    status: MoveStatus
    reason: str = ""  #: one of REFUSAL_REASONS / FAILURE_REASONS unless reached
    detail: str = ""  #: the arm's own words (an exception message), for the log
    seconds: float = 0.0  #: wall time from the command to the end of the gripper action
    position_error: float = float("nan")  #: distance of the grasp frame from the target at the end, metres
    timings: dict[str, float] = field(default_factory=dict)  #: seconds per stage (arm, gripper)

    @property
    def reached(self) -> bool:
        return self.status == "reached"


@runtime_checkable
class RobotArm(Protocol):
    """Any arm the robot actor can drive (a Franka through franky; another arm by implementing this)."""

    def connect(self) -> None:
        """Open the connection and apply the configured dynamics and collision limits."""

    def observe(self, step: int = 0) -> Observation:
        """Camera frames plus proprioception, in the simulator's Observation layout."""

    def move_to(self, pose: np.ndarray, gripper_open: bool) -> MoveResult:
        """Move the grasp frame to ``pose`` (xyz + quaternion xyzw, robot base frame), then open or close."""

    def recover(self) -> bool:
        """Clear an arm error (reconnecting when the connection was lost); True when the arm can move again."""

    def unwind(self) -> bool:
        """Move to the arm's known posture in joint space (no Cartesian path to get stuck on); True when there."""

    def stop(self) -> float:
        """Halt any motion now and refuse moves until ``resume()``; returns seconds until the arm stood still."""

    def resume(self) -> None:
        """Accept moves again after ``stop()``."""

    def disconnect(self) -> None:
        """Release the arm; safe to call twice."""


def return_home(arm: RobotArm, home: np.ndarray) -> MoveResult:
    """Move to ``home`` (gripper open); on failure clear the error, unwind in joint space and try once more.

    A Cartesian move can fail for reasons one recovery fixes (an arm error left by the last
    motion, a trajectory the arm's generator rejects from a twisted posture); a second failure
    is returned for the caller to act on.
    """
    result = arm.move_to(np.asarray(home, dtype=float), gripper_open=True)
    if not result.reached:
        arm.recover()
        arm.unwind()
        result = arm.move_to(np.asarray(home, dtype=float), gripper_open=True)
    return result
