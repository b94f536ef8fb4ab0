"""The task ladder (reference/tasks.md section 6) and its registry: ``make_task(name)``, ``TASKS``."""

from __future__ import annotations

from actors.sim.task_names import TASKS
from actors.sim.tasks.base import DEFAULT_BOUNDS, Task, Waypoint
from actors.sim.tasks.lift_lid import LiftLid
from actors.sim.tasks.open_drawer import OpenDrawer
from actors.sim.tasks.pick_and_lift import PickAndLift
from actors.sim.tasks.push_button import PushButton
from actors.sim.tasks.put_in_bin import PutInBin
from actors.sim.tasks.put_item_in_drawer import PutItemInDrawer
from actors.sim.tasks.reach_target import ReachTarget
from actors.sim.tasks.stack_wine import StackWine

_REGISTRY: dict[str, type[Task]] = {t.name: t for t in (
    ReachTarget, PushButton, PickAndLift, LiftLid, OpenDrawer, PutInBin, StackWine, PutItemInDrawer)}
if tuple(_REGISTRY) != TASKS:  # task_names.py is what the command line shows before pybullet loads
    raise ImportError(f"actors/sim/task_names.py lists {TASKS}, the registry holds {tuple(_REGISTRY)}")


class UnknownTaskError(ValueError):
    """A task name that is not in the ladder; the message lists the ones that are."""

    def __init__(self, name: str) -> None:
        super().__init__(f"unknown task {name!r}; available tasks: {', '.join(TASKS)}")
        self.name = name


def make_task(name: str) -> Task:
    """A fresh task object by name."""
    try:
        return _REGISTRY[name]()
    except KeyError:
        raise UnknownTaskError(name) from None


__all__ = ["DEFAULT_BOUNDS", "TASKS", "Task", "UnknownTaskError", "Waypoint", "make_task"]
