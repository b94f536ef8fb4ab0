"""Typed configuration of the simulated actor world (one dataclass, one line of doc per field)."""

from __future__ import annotations

from dataclasses import dataclass

from actors.sim.task_names import DEFAULT_TASK
from protocol.observation import CAMERA_NAMES


@dataclass
class SimConfig:
    """What an actor's PyBullet world looks like and how it executes next-best poses."""

    task: str = DEFAULT_TASK  #: task name, one of ``actors.sim.task_names.TASKS``
    cameras: tuple[str, ...] = ("front",)  #: cameras rendered into each observation, any subset of CAMERA_NAMES
    image_size: int = 128  #: square image side in pixels (RLBench/C2F-ARM use 128)
    episode_length: int | None = None  #: next-best-pose decisions per episode; None = the task's own length
    seed: int = 0  #: seed of the first episode when reset() is called without one
    physics_hz: int = 240  #: physics steps per simulated second
    control_hz: int = 20  #: joint-controller (and demo recording) steps per second
    unreachable_reward: float = 0.0  #: reward when a pose is unreachable (0 as the reference, -1 as the paper)
    planner: str = "RRTConnect"  #: OMPL geometric planner name (SBL falls back to LBKPIECE1)
    planning_time: float = 1.0  #: OMPL solve budget per pose, seconds
    simplify_time: float = 0.1  #: OMPL path-simplification budget, seconds
    velocity_scale: float = 0.5  #: fraction of the Panda's joint velocity limits used by Ruckig
    acceleration_scale: float = 0.5  #: fraction of the Panda's acceleration and jerk limits used by Ruckig
    fov_deg: float = 60.0  #: vertical field of view of the fixed cameras, degrees

    def __post_init__(self) -> None:
        unknown = [c for c in self.cameras if c not in CAMERA_NAMES]
        if unknown:
            raise ValueError(f"unknown cameras {unknown}; choose from {CAMERA_NAMES}")
        self.cameras = tuple(self.cameras)


