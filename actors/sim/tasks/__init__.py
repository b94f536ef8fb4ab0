"""The task ladder's scenes and their registry: ``make_task(name)``; the ladder itself is ``actors.sim.task_specs``."""

from __future__ import annotations

from actors.sim.task_specs import DEFAULT_BOUNDS, TASKS, UnknownTaskError
from actors.sim.tasks.base import Task, Waypoint
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
if tuple(_REGISTRY) != TASKS:  # task_specs.py is what the command line shows before pybullet loads
    raise ImportError(f"actors/sim/task_specs.py lists {TASKS}, the registry holds {tuple(_REGISTRY)}")


def make_task(name: str) -> Task:
    """A fresh task object by name."""
    try:
        return _REGISTRY[name]()
    except KeyError:
        raise UnknownTaskError(name) from None


__all__ = ["DEFAULT_BOUNDS", "TASKS", "Task", "UnknownTaskError", "Waypoint", "make_task"]
