"""Joint-space motion planning: the straight joint-space segment when it is collision-free (as PyRep
tries a linear path first), otherwise an OMPL geometric planner, then path simplification.

Budgets are CPU seconds of the actor's own process, not wall-clock seconds: on a 2-core machine
shared with a learner, a process at nice 19 got about half a core (half a second of planning per
wall-clock second), and scripted demos then failed `planning_failed` on 3 of 10 seeds that an idle
machine solved 10/10. Counting CPU time makes what is reachable independent of the machine's load.

OMPL 2.0.1's wheel has no SBL (the paper's planner); "SBL" falls back to its lazy bi-directional
cousin LBKPIECE1. RRTConnect is the default because it measured fastest (bench/bench_sim.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from actors.control.collision import CollisionWorld
from actors.control.limits import LOWER, UPPER

ou.setLogLevel(ou.LOG_ERROR)
PLANNERS = ("RRTConnect", "LBKPIECE1", "BKPIECE1", "KPIECE1", "PRM", "RRT", "SBL")


def planner_class(name: str):
    """OMPL planner class by name; SBL is absent from the 2.0.1 wheel and maps to LBKPIECE1."""
    if name == "SBL":
        return getattr(og, "SBL", og.LBKPIECE1)
    if name not in PLANNERS or not hasattr(og, name):
        raise ValueError(f"unknown planner {name!r}; choose from {PLANNERS}")
    return getattr(og, name)


_SEEDED = False


def _seed_once(seed: int) -> None:
    """OMPL's RNG can be seeded once per process, before first use; later plans are not replayable."""
    global _SEEDED
    if not _SEEDED:
        ou.RNG.setSeed(int(seed) + 1)
        _SEEDED = True


#: However starved the process, a budget ends after this many times its CPU seconds in wall-clock time.
WALL_CAP = 10.0


def cpu_budget(seconds: float) -> ob.PlannerTerminationCondition:
    """Terminates OMPL once this process has spent `seconds` of CPU time from now (all its threads:
    the planner's, and nothing else runs while an actor plans), or WALL_CAP times that in wall time."""
    deadline = time.process_time() + seconds
    return ob.plannerOrTerminationCondition(
        ob.PlannerTerminationCondition(lambda: time.process_time() >= deadline),
        ob.timedPlannerTerminationCondition(WALL_CAP * seconds))


@dataclass
class Plan:
    """A collision-free piecewise-linear joint path [N, 7] (N >= 2)."""

    path: np.ndarray
    used_ompl: bool
    checks: int


#: Largest joint-space step (radians) between two collision checks along a motion.
CHECK_RESOLUTION = 0.01


def segment_is_free(world: CollisionWorld, a: np.ndarray, b: np.ndarray, resolution: float = 0.02) -> bool:
    n = max(2, int(np.ceil(np.abs(b - a).max() / resolution)) + 1)
    return all(world.is_valid(a + (b - a) * t) for t in np.linspace(0.0, 1.0, n))


class MotionPlanner:
    def __init__(self, world: CollisionWorld, planner: str = "RRTConnect", planning_time: float = 1.0,
                 simplify_time: float = 0.1, seed: int = 0) -> None:
        self.world, self.planning_time, self.simplify_time = world, planning_time, simplify_time
        self.planner_cls = planner_class(planner)
        _seed_once(seed)
        self.space = ob.RealVectorStateSpace(7)
        bounds = ob.RealVectorBounds(7)
        for i in range(7):
            bounds.setLow(i, float(LOWER[i]))
            bounds.setHigh(i, float(UPPER[i]))
        self.space.setBounds(bounds)

    def plan(self, start: np.ndarray, goal: np.ndarray) -> Plan | None:
        """A path from start to goal, or None when the goal is in collision or OMPL finds nothing."""
        self.world.checks = 0
        # RLBench makes shapes already touching the arm non-collidable while planning: same here.
        self.world.allowed = set(self.world.contacts(start))
        if not self.world.is_valid(goal):
            return None
        if segment_is_free(self.world, start, goal):
            return Plan(np.stack([start, goal]), False, self.world.checks)
        ss = og.SimpleSetup(self.space)
        ss.setStateValidityChecker(lambda s: self.world.is_valid([s[i] for i in range(7)]))
        si = ss.getSpaceInformation()
        # OMPL's resolution is a fraction of the space's extent: make it CHECK_RESOLUTION radians.
        si.setStateValidityCheckingResolution(CHECK_RESOLUTION / self.space.getMaximumExtent())
        a, b = self.space.allocState(), self.space.allocState()
        inside = np.clip(start, LOWER + 1e-6, UPPER - 1e-6)  # the physics may sit a hair past a limit
        for i in range(7):
            a[i], b[i] = float(inside[i]), float(goal[i])
        ss.setStartAndGoalStates(a, b)
        ss.setPlanner(self.planner_cls(si))
        ss.solve(cpu_budget(self.planning_time))
        if not ss.haveExactSolutionPath():
            return None
        ss.simplifySolution(cpu_budget(self.simplify_time))
        path = ss.getSolutionPath()
        wps = np.array([[path.getState(k)[i] for i in range(7)] for k in range(path.getStateCount())])
        wps[0] = start
        # OMPL checks motions at discrete states; re-check the final path as densely as the
        # executor will move, so a grazing contact between two checks never reaches the robot.
        if not all(segment_is_free(self.world, x, y, CHECK_RESOLUTION) for x, y in zip(wps[:-1], wps[1:])):
            return None
        return Plan(wps, True, self.world.checks)
