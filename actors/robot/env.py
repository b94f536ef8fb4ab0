"""RobotEnv: a real arm with the simulator's shape (reset / step / reachable / observe), for the actor loop.

One step is one next-best pose, executed by the arm (safety limits first). The reward and the
end of an episode come from the operator: "success" gives the simulator's success reward and
ends the episode, "fail" ends it with 0, and an episode that runs out of decisions waits
``verdict_wait_s`` for a word before it ends as a timeout with reward 0. A refused or failed
move ends the episode as "unreachable", as in the simulator. Each episode starts with the arm
at its home pose and, unless told otherwise, the operator's "reset done". Every observation
carries the robot's depth-0 box (``robot.scene_bounds``, by default the safety workspace), so
the policy picks among poses the safety limits let through.

An operator stop mid-episode raises :class:`OperatorStopped`: a cut-short episode is not data.
"""

from __future__ import annotations

import threading
from typing import Protocol

import numpy as np

from actors.environment import SUCCESS_REWARD, StepResult
from actors.robot.config import RobotConfig
from actors.robot.interface import RobotArm, return_home
from actors.robot.operator import OperatorChannel
from protocol.messages import OperatorAction
from protocol.observation import Observation
from protocol.transition import stamp_scene_bounds

VERDICTS = {OperatorAction.SUCCESS, OperatorAction.FAIL}


class OperatorStopped(Exception):
    """The operator stopped the arm (or the role is stopping) during an episode."""


class ScriptedOperator(Protocol):
    """Stands in for the person where a program can judge the task (franky-sim benchmarks and tests)."""

    def before_reset(self, rng: np.random.Generator) -> None:
        """Set the scene up for a new episode, then say "reset done" on the channel."""

    def after_move(self, observation: Observation) -> None:
        """Say "success" on the channel when the task is done."""


class RobotEnv:
    """A robot arm, an operator and a task, with PandaEnv's interface."""

    def __init__(self, arm: RobotArm, channel: OperatorChannel, config: RobotConfig, task: str,
                 episode_length: int, stop: threading.Event,
                 scripted: ScriptedOperator | None = None, unreachable_reward: float = 0.0) -> None:
        self.arm, self.channel, self.config = arm, channel, config
        self.task_name, self.episode_length, self.scene_bounds = task, episode_length, config.depth0_bounds
        self.stop, self.scripted, self.unreachable_reward = stop, scripted, unreachable_reward
        self.steps = 0
        self.seed: int | None = None

    def reset(self, seed: int | None = None) -> Observation:
        """Arm home, then (the operator's) "reset done"; raises OperatorStopped if stopped meanwhile."""
        self.seed = 0 if seed is None else int(seed)
        self._wait_resumed()
        home = return_home(self.arm, np.asarray(self.config.home))
        if not home.reached:
            raise OperatorStopped(f"cannot reach the home pose: {home.reason} {home.detail}")
        self.channel.discard((VERDICTS | {OperatorAction.RESET_DONE}) if self.scripted else VERDICTS)
        if self.scripted is not None:
            self.scripted.before_reset(np.random.default_rng(self.seed))
        if self.config.wait_for_reset or self.scripted is not None:
            if self.channel.wait_for({OperatorAction.RESET_DONE}, self.stop) is None:
                raise OperatorStopped("stopped while waiting for reset done")
        self.steps = 0
        return self.observe()

    def step(self, action: np.ndarray) -> StepResult:
        action = np.asarray(action, dtype=float)
        if self.channel.paused or self.stop.is_set():
            raise OperatorStopped("paused")
        result = self.arm.move_to(action[:7], gripper_open=bool(action[7] > 0.5))
        if result.reason == "stopped":
            raise OperatorStopped("stopped during a move")
        if result.status == "failed" and result.reason in ("control_error", "connection_lost"):
            self.arm.recover()  # the episode ends; the next one starts from a working arm
        self.steps += 1
        obs = self.observe()
        info = {"timings": result.timings, "move_s": result.seconds}
        if not result.reached:
            info["reason"] = result.reason
            return StepResult(obs, self.unreachable_reward, True, False, True, info)
        if self.scripted is not None:
            self.scripted.after_move(obs)
        verdict = self.channel.take(VERDICTS)
        if verdict is None and self.steps >= self.episode_length and self.scripted is None:
            # a person may still be judging; a scripted operator has judged after the move already
            verdict = self.channel.wait_for(VERDICTS, self.stop, self.config.verdict_wait_s)
        success = verdict is OperatorAction.SUCCESS
        info["timeout"] = verdict is None and self.steps >= self.episode_length
        return StepResult(obs, SUCCESS_REWARD if success else 0.0, verdict is not None or info["timeout"], success,
                          False, info)

    def reachable(self, action: np.ndarray) -> bool:
        """Whether the safety limits would let this pose through (no motion, nothing counted)."""
        return self.arm.safety.allows(np.asarray(action, dtype=float)[:7], self.arm.grasp_pose()[:3])

    def observe(self) -> Observation:
        observation = self.arm.observe(self.steps)
        stamp_scene_bounds([observation], self.scene_bounds)  # the learner voxelises it in the robot's box
        return observation

    def _wait_resumed(self) -> None:
        if self.channel.paused and not self.channel.wait_resumed(self.stop):
            raise OperatorStopped("stopped while paused")
        if self.stop.is_set():
            raise OperatorStopped("role stopping")

    def close(self) -> None:
        self.arm.disconnect()
