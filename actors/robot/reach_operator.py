"""The scripted operator of franky-sim's reach task: it sets each scene up, demonstrates and judges."""

from __future__ import annotations

import numpy as np

from actors.robot.demos import TOP_DOWN, Waypoint
from actors.robot.operator import OperatorChannel
from protocol.messages import OperatorAction
from protocol.observation import Observation


class ReachOperator:
    """The scripted operator of franky-sim's reach task: success within 2 cm of the target.

    It also demonstrates the task (``c2farm robot-demos`` with ``robot.scripted_operator``): the
    target where an episode of that seed would have it, then one top-down move onto it.
    """

    def __init__(self, sim, channel: OperatorChannel, low=(0.35, -0.2, 0.1), high=(0.6, 0.2, 0.35),
                 radius: float = 0.02) -> None:
        self.sim, self.channel, self.low, self.high, self.radius = sim, channel, low, high, radius

    def place_target(self, rng: np.random.Generator) -> np.ndarray:
        """Move the target somewhere new in its box; where it went."""
        self.sim.set_target(rng.uniform(self.low, self.high))
        return np.asarray(self.sim.target, dtype=float)

    def before_reset(self, rng: np.random.Generator) -> None:
        self.place_target(rng)
        self.channel.put(OperatorAction.RESET_DONE, "scripted")

    def demonstration(self, rng: np.random.Generator) -> list[Waypoint]:
        """Set a demo's scene up; its one waypoint (a keyframe): the grasp frame onto the target, top-down."""
        return [Waypoint(np.array([*self.place_target(rng), *TOP_DOWN]), gripper_open=True)]

    def after_move(self, observation: Observation) -> None:
        if np.linalg.norm(observation.gripper_pose[:3] - self.sim.target) < self.radius:
            self.channel.put(OperatorAction.SUCCESS, "scripted")
