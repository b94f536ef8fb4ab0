"""Simulation and control timings: render per observation (1 and 4 cameras), the control agent per
next-best pose split into IK / planning / Ruckig / physics execution / gripper, planning success rate,
and OMPL planners compared on a pose that needs a detour.

    .venv/bin/python bench/bench_sim.py --episodes 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from actors.control.collision import CollisionWorld
from actors.control.ik import IKSolver
from actors.control.planner import MotionPlanner
from actors.demos.generate import record_demo
from actors.panda_env import PandaEnv
from actors.sim import TASKS, SimConfig, shapes
from actors.sim.scene import HOME
from actors.sim.tasks.base import top_down

ALL = ("front", "left_shoulder", "right_shoulder", "wrist")


def render_times(task: str, n: int = 10) -> tuple[float, float]:
    out = []
    for cams in (("front",), ALL):
        env = PandaEnv(SimConfig(task=task, cameras=cams))
        env.reset(0)
        t = time.perf_counter()
        for _ in range(n):
            env.observe()
        out.append((time.perf_counter() - t) / n * 1e3)
        env.close()
    return out[0], out[1]


def control_times(task: str, episodes: int) -> dict[str, float]:
    env = PandaEnv(SimConfig(task=task, cameras=()))
    stages: dict[str, list[float]] = {k: [] for k in ("ik", "plan", "trajectory", "execute", "gripper")}
    poses = planned = ompl = 0
    for s in range(episodes):
        env.reset(s)
        for wp in env.demo_waypoints():
            r = env.step(wp.action(), linear=wp.linear)
            poses += 1
            planned += not r.unreachable
            ompl += r.info["used_ompl"]
            for k, v in r.info["timings"].items():
                stages[k].append(v)
            if r.unreachable:
                break
    env.close()
    res = {k: 1e3 * float(np.mean(v)) if v else float("nan") for k, v in stages.items()}
    res["success"] = planned / poses
    res["ompl"] = ompl / poses
    return res


def planner_comparison(trials: int = 5) -> None:
    world = CollisionWorld()
    wall = shapes.box(world.client, (0.1, 0.02, 0.2), (0.5, 0.0, 0.2))
    world.set_obstacles([wall], [])
    ik = IKSolver(world)
    a = ik.solve((0.5, 0.25, 0.15), top_down(0.0), HOME, accept=world.is_valid)
    b = ik.solve((0.5, -0.25, 0.15), top_down(0.0), a, accept=world.is_valid)
    print("\n| planner (wall detour) | solved | mean ms (plan + simplify 0.1 s budget) | path vertices |")
    print("|---|---|---|---|")
    for name in ("RRTConnect", "LBKPIECE1", "BKPIECE1", "PRM", "RRT"):
        mp = MotionPlanner(world, name, planning_time=2.0)
        times, ok, verts = [], 0, []
        for _ in range(trials):
            t = time.perf_counter()
            plan = mp.plan(a, b)
            times.append(time.perf_counter() - t)
            if plan is not None:
                ok += 1
                verts.append(len(plan.path))
        print(
            f"| {name} | {ok}/{trials} | {1e3 * np.mean(times):.0f} | {np.mean(verts) if verts else float('nan'):.1f} |"
        )
    world.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--episodes", type=int, default=5, help="scripted episodes per task for control timings")
    args = ap.parse_args()
    print("| task | render 1 cam ms | render 4 cams ms | IK ms | plan ms | Ruckig ms | physics exec ms | gripper ms "
          "| pose reached | OMPL used | frames/s recorded (no cams) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for task in TASKS:
        r1, r4 = render_times(task)
        c = control_times(task, args.episodes)
        env = PandaEnv(SimConfig(task=task, cameras=()))
        t = time.perf_counter()
        d = record_demo(env, 0)
        fps = len(d.observations) / (time.perf_counter() - t)
        env.close()
        print(
            f"| {task} | {r1:.1f} | {r4:.1f} | {c['ik']:.1f} | {c['plan']:.1f} | {c['trajectory']:.2f} | "
            f"{c['execute']:.1f} | {c['gripper']:.1f} | {100 * c['success']:.0f}% | {100 * c['ompl']:.0f}% "
            f"| {fps:.0f} |",
            flush=True,
        )
    planner_comparison()


if __name__ == "__main__":
    main()
