"""The task ladder, easiest first: each task's name and the facts other processes need, without the physics engine.

Command-line help, pre-flight checks and the learner (its Q-attention config) need a task's
decision budget and depth-0 box before anything simulates, so they live here, once; the task
classes in ``actors.sim.tasks`` (which import pybullet) read them from this table.
"""

from __future__ import annotations

from dataclasses import dataclass

#: The depth-0 box (min xyz, max xyz, metres, world frame) of every task. The reference's is a 1 m cube
#: above its table; ours sits over our table.
DEFAULT_BOUNDS: tuple[float, ...] = (-0.1, -0.5, -0.05, 0.9, 0.5, 0.95)


@dataclass(frozen=True)
class TaskSpec:
    """What the rest of the system knows of a task without simulating it."""

    name: str  #: the name ``sim.task`` takes
    episode_length: int  #: decisions (next-best poses) per episode before it times out
    revision: int = 1  #: raised when the scene a seed draws changes, so demos cached for the old scene are not reused
    scene_bounds: tuple[float, ...] = DEFAULT_BOUNDS  #: the depth-0 box Q-attention voxelises


TASK_SPECS: dict[str, TaskSpec] = {s.name: s for s in (
    TaskSpec("reach_target", 3),
    TaskSpec("push_button", 5, revision=2),  # 2: the base keeps its grey (1 painted it one of 20 colours per episode)
    TaskSpec("pick_and_lift", 6, revision=2),  # 2: the target is always red (1 drew its colour at random)
    TaskSpec("lift_lid", 6, revision=2),  # 2: the saucepan is always grey (1 drew its colour from four per episode)
    TaskSpec("open_drawer", 6, revision=3),  # 2: the approach stops 5 cm before the handle (1: 10 cm);
    # 3: always the bottom drawer, RLBench's variation 0 (1-2: one of three at random, unobservable), approached
    # from 10 cm again (from 5 cm the hand missed the handle in 9 of 100 demos)
    TaskSpec("put_in_bin", 8, revision=3),  # 2: the demo lets go 13 cm above the bin's floor (1: 20 cm, unseen);
    # 3: and approaches the block 5 cm above it (2: 10 cm)
    TaskSpec("stack_wine", 10, revision=3),  # 2: approach and turn 5 cm above grasp and cradle (1: 8, 15);
    # 3: the bottle always left of the rack, RLBench's one layout (1-2: the pair mirrored across x at random)
    TaskSpec("put_item_in_drawer", 15, revision=4),  # 2: the block's approach 5 cm above it (1: 10 cm);
    # 3: always the bottom drawer, as open_drawer; 4: the chest always left of the arm, the block right (1-3: mirrored
    # across x at random)
)}
TASKS: tuple[str, ...] = tuple(TASK_SPECS)
#: The task ``sim.task`` names unless a preset or the command line says otherwise.
DEFAULT_TASK = "reach_target"


class UnknownTaskError(ValueError):
    """A task name that is not in the ladder; the message lists the ones that are."""

    def __init__(self, name: str) -> None:
        super().__init__(f"unknown task {name!r}; available tasks: {', '.join(TASKS)}")
        self.name = name


def task_spec(name: str) -> TaskSpec:
    """The spec of task ``name``; UnknownTaskError if the ladder has no such task."""
    try:
        return TASK_SPECS[name]
    except KeyError:
        raise UnknownTaskError(name) from None
