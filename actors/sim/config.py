"""Typed configuration of the simulated actor world (one dataclass, one line of doc per field)."""

from __future__ import annotations

from dataclasses import dataclass

from actors.sim.task_specs import DEFAULT_TASK
from protocol.config_checks import above, at_least, distinct, finite, non_empty, one_of, within
from protocol.observation import CAMERA_NAMES

#: OMPL planners an actor can use (``actors.control.planner.PLANNERS``, which imports OMPL;
#: tests/test_config.py keeps the two equal).
PLANNERS = ("RRTConnect", "LBKPIECE1", "BKPIECE1", "KPIECE1", "PRM", "RRT", "SBL")


@dataclass
class SimConfig:
    """What an actor's PyBullet world looks like and how it executes next-best poses."""

    task: str = DEFAULT_TASK  #: task name, one of ``actors.sim.task_specs.TASKS``
    #: cameras rendered into each observation, any subset of CAMERA_NAMES, each once
    cameras: tuple[str, ...] = ("front",)
    image_size: int = 128  #: square image side in pixels, >= 8 (RLBench/C2F-ARM use 128)
    episode_length: int | None = None  #: next-best-pose decisions per episode, >= 1; None = the task's own length
    seed: int = 0  #: seed of the first episode when reset() is called without one, >= 0
    physics_hz: int = 240  #: physics steps per simulated second, >= control_hz
    control_hz: int = 20  #: joint-controller (and demo recording) steps per second, >= 1
    unreachable_reward: float = 0.0  #: reward when a pose is unreachable (0 as the reference, -1 as the paper)
    #: OMPL geometric planner: RRTConnect, LBKPIECE1, BKPIECE1, KPIECE1, PRM, RRT or SBL (falls back to LBKPIECE1)
    planner: str = "RRTConnect"
    planning_time: float = 1.0  #: OMPL solve budget per pose, CPU seconds of the actor, > 0
    simplify_time: float = 0.1  #: OMPL path-simplification budget, CPU seconds, >= 0
    velocity_scale: float = 0.5  #: fraction of the Panda's joint velocity limits used by Ruckig, in (0, 1]
    acceleration_scale: float = 0.5  #: fraction of the Panda's acceleration and jerk limits used by Ruckig, in (0, 1]
    fov_deg: float = 60.0  #: vertical field of view of the fixed cameras, degrees, in (0, 180)

    def __post_init__(self) -> None:
        unknown = [c for c in self.cameras if c not in CAMERA_NAMES]
        if unknown:
            raise ValueError(f"unknown cameras {unknown}; choose from {CAMERA_NAMES}")
        self.cameras = tuple(self.cameras)
        non_empty(self, "task")  # a known one: deploy/preflight.py, which names the tasks
        distinct(self, "cameras")
        at_least(self, 8, "image_size")
        at_least(self, 1, "episode_length", "control_hz")
        at_least(self, 0, "seed", "simplify_time")
        if self.physics_hz < self.control_hz:
            raise ValueError(f"physics_hz must be >= control_hz ({self.control_hz}) (got {self.physics_hz})")
        finite(self, "unreachable_reward")
        one_of(self, "planner", PLANNERS)
        above(self, 0, "planning_time")
        within(self, 0, 1, "velocity_scale", "acceleration_scale", open_low=True)
        within(self, 0, 180, "fov_deg", open_low=True, open_high=True)


