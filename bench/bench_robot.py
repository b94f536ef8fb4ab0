"""The robot path on franky-sim: pose-to-pose motion time, stop-to-still time, one decision's latency.

Drives franky-sim through ``FrankaArm`` (franky, libfranka's protocol on loopback) between random
reachable top-down poses; stops a move half-way for the stop figure. franky-sim steps a Python
1 kHz loop, which runs slower than real time on a busy machine: the simulated seconds are
reported beside the wall clock.

A decision is timed stage by stage: capture (camera render + arm state), act (voxelise + the
Q-attention cascade of the cpu-small preset, untrained weights: the cost does not depend on them),
command (the move, its settling and the gripper).

    .venv/bin/python bench/bench_robot.py --moves 10 --stops 5 --decisions 10
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time

import numpy as np

from actors.robot.config import FrankaConfig, SafetyConfig
from actors.robot.franka import FrankaArm
from actors.robot.franky_sim import FrankySim

DOWN = np.array([1.0, 0.0, 0.0, 0.0])


def stats(values) -> dict[str, float]:
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=float)
    return (
        {"n": int(v.size), "median": round(float(np.median(v)), 3), "max": round(float(v.max()), 3)}
        if v.size
        else {"n": 0}
    )


def decide(arm: FrankaArm, n: int, seed: int) -> dict:
    """Time capture -> voxelise + cascade -> command, ``n`` times, with the cpu-small networks."""
    import torch

    from actors.sim.tasks import make_task
    from qattention.agent import C2FARM
    from qattention.batch import ObservationBatch
    from qattention.config import cpu_small

    torch.manual_seed(seed)
    torch.set_num_threads(1)
    config = cpu_small().replace(cameras=("front",), scene_bounds=tuple(make_task("reach_target").scene_bounds))
    agent = C2FARM(config, device=torch.device("cpu"))
    capture, act, command = [], [], []
    for _ in range(n):
        arm.resume()
        t0 = time.perf_counter()
        obs = arm.observe()
        t1 = time.perf_counter()
        action = agent.act(ObservationBatch.from_observations([obs], config.cameras, agent.device)).action[0]
        t2 = time.perf_counter()
        arm.move_to(np.asarray(action[:7], dtype=float), bool(action[7] > 0.5))  # mostly refused: untrained
        command.append(time.perf_counter() - t2)
        capture.append(t1 - t0)
        act.append(t2 - t1)
    return {"decision_capture_s": stats(capture), "decision_act_s (voxelise + cascade)": stats(act),
            "decision_command_s (refused or moved)": stats(command)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--moves", type=int, default=10, help="pose-to-pose moves to time")
    ap.add_argument("--stops", type=int, default=5, help="moves stopped half-way")
    ap.add_argument("--dynamics", type=float, default=0.2, help="franky relative dynamics factor")
    ap.add_argument("--decisions", type=int, default=10, help="timed capture -> act -> command decisions")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    out: dict = {"load_avg_1min": os.getloadavg()[0], "dynamics_factor": args.dynamics}
    with FrankySim() as sim:
        arm = FrankaArm(FrankaConfig(host=sim.hostname, dynamics_factor=args.dynamics), SafetyConfig(max_step=1.0),
                        [sim.camera("front")])
        arm.connect()
        wall, simulated, distance, errors, observe = [], [], [], [], []
        for _ in range(args.moves):
            target = np.concatenate([rng.uniform((0.35, -0.25, 0.15), (0.65, 0.25, 0.45)), DOWN])
            start, s0 = arm.grasp_pose()[:3], sim.sim_time()
            result = arm.move_to(target, gripper_open=True)
            if result.reached:
                wall.append(result.seconds)
                simulated.append(sim.sim_time() - s0)
                distance.append(float(np.linalg.norm(target[:3] - start)))
                errors.append(result.position_error * 1000)
            t = time.perf_counter()
            arm.observe()
            observe.append(time.perf_counter() - t)
        stop_wall, stop_sim = [], []
        for _ in range(args.stops):
            arm.resume()
            arm.move_to(np.concatenate([[0.45, 0.2, 0.3], DOWN]), gripper_open=True)
            mover = threading.Thread(target=arm.move_to, args=(np.concatenate([[0.6, -0.25, 0.35], DOWN]), True))
            mover.start()
            time.sleep(0.8)
            s0 = sim.sim_time()
            stop_wall.append(arm.stop())
            stop_sim.append(sim.sim_time() - s0)
            mover.join()
        decisions = decide(arm, args.decisions, args.seed) if args.decisions else {}
        arm.disconnect()
    out.update(decisions)
    out.update({
        "move_wall_s": stats(wall), "move_sim_s": stats(simulated), "move_distance_m": stats(distance),
        "final_error_mm": stats(errors), "observe_s (1 camera 128px + state)": stats(observe),
        "stop_to_still_wall_s": stats(stop_wall), "stop_to_still_sim_s": stats(stop_sim),
        "load_avg_1min_after": os.getloadavg()[0]})
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
