"""The environment an actor acts in, whichever world it is: the simulator's ``PandaEnv`` or a real arm's ``RobotEnv``.

One step is one C2F-ARM decision: a next-best pose (xyz, quaternion xyzw, gripper open) that the
world executes and then reports on. Rewards are sparse: ``SUCCESS_REWARD`` when the task is done
(which ends the episode), else 0; a pose the world cannot take ends the episode as unreachable.
The actor loop (``actors.actor_loop.rollout``) only uses what :class:`Env` declares.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from protocol.observation import Observation

#: The reward of the step that completes the task (the reference's RLBench reward); every other step earns 0.
SUCCESS_REWARD = 100.0


@dataclass
class StepResult:
    """What became of one next-best pose."""

    observation: Observation  #: the world after the move (and the gripper action)
    reward: float  #: SUCCESS_REWARD on success, else 0 (or the unreachable reward)
    terminal: bool  #: the episode ended here: success, out of decisions, or unreachable
    success: bool  #: the task is done
    unreachable: bool  #: the pose could not be taken (refused, no IK, no path, the arm failed)
    info: dict = field(default_factory=dict)  #: reason (when unreachable), timings, control_steps, timeout


@runtime_checkable
class Env(Protocol):
    """A world one actor acts in, one next-best pose per step."""

    task_name: str  #: the task, as ``sim.task`` names it
    episode_length: int  #: decisions per episode before it times out
    scene_bounds: tuple[float, ...]  #: the depth-0 box every observation is voxelised in (min xyz, max xyz)

    def reset(self, seed: int | None = None) -> Observation:
        """Start an episode (its scene drawn from ``seed``) and return the first observation."""

    def step(self, action: np.ndarray) -> StepResult:
        """Execute one next-best pose ([8]: xyz, quaternion xyzw, gripper open > 0.5) and say what became of it."""

    def reachable(self, action: np.ndarray) -> bool:
        """Whether the world would take ``action`` from where the arm is now (checked before acting)."""

    def observe(self) -> Observation:
        """The cameras and proprioception now."""

    def close(self) -> None:
        """Release the world (simulator, connection); safe to call twice."""
