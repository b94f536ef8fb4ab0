"""The whole system's throughput, and what one decision costs an actor.

    python bench/bench_system.py decision [--task reach_target] [--decisions 20]
    python bench/bench_system.py system --actors 1 2 [--minutes 4] [--preset cpu-small]

``decision`` times, in one process, the parts of one next-best-pose decision: render the
cameras (1 and 4), voxelise + run the cascade (the cpu-small and paper networks), and execute
the pose through the control agent (the task's scripted waypoints, so every pose is reachable).

``system`` runs ``c2farm launch`` (router, replay, learner, N actors, evaluator, dashboard) for
each actor count, discards the first minute, and reads the dashboard: env steps/s per actor
and in total, learner updates/s and samples/s, and the weight broadcast latency at the actors
(publish to receipt, wall clocks of one host).
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import time


def time_decisions(task: str, decisions: int) -> None:
    import torch

    from actors.panda_env import PandaEnv
    from actors.sim import SimConfig
    from qattention.agent import C2FARM
    from qattention.batch import ObservationBatch
    from qattention.config import cpu_small, paper

    torch.set_num_threads(1)
    print(f"one decision on {task} (median ms of {decisions} poses), 1 torch thread")
    print("| cameras | network | render | voxelise + cascade | IK | plan | Ruckig | physics + gripper | total |")
    print("|---|---|---|---|---|---|---|---|---|")
    for cameras in (("front",), ("front", "left_shoulder", "right_shoulder", "wrist")):
        env = PandaEnv(SimConfig(task=task, cameras=cameras))
        for name, preset in (("cpu-small", cpu_small()), ("paper", paper())):
            config = preset.replace(scene_bounds=tuple(env.scene_bounds), cameras=cameras,
                                    episode_length=env.episode_length)
            agent = C2FARM(config, device="cpu")
            parts: dict[str, list[float]] = {k: [] for k in ("render", "act", "ik", "plan", "trajectory", "physics")}
            seed = 0
            while len(parts["render"]) < decisions:
                env.reset(seed=seed)
                seed += 1
                for waypoint in env.demo_waypoints():  # scripted poses: every one is reachable
                    t0 = time.perf_counter()
                    obs = env.observe()
                    t1 = time.perf_counter()
                    agent.act(ObservationBatch.from_observations([obs], cameras, "cpu"))
                    t2 = time.perf_counter()
                    result = env.step(waypoint.action(), linear=waypoint.linear)
                    if result.unreachable:
                        break
                    timings = result.info["timings"]
                    parts["render"].append(t1 - t0)
                    parts["act"].append(t2 - t1)
                    for k in ("ik", "plan", "trajectory"):
                        parts[k].append(timings.get(k, 0.0))
                    parts["physics"].append(timings.get("execute", 0.0) + timings.get("gripper", 0.0))
                    if result.terminal or len(parts["render"]) >= decisions:
                        break
            ms = {k: 1e3 * statistics.median(v) for k, v in parts.items()}
            cells = " | ".join(f"{ms[k]:.1f}" for k in parts)
            print(f"| {len(cameras)} | {name} | {cells} | {sum(ms.values()):.0f} |", flush=True)
        env.close()


def measure_system(actors: list[int], minutes: float, preset: str, task: str) -> None:
    import httpx

    print(f"system on {task}, preset {preset}, {minutes:g} min per row (first minute discarded)")
    print(
        "| actors | env steps/s total | env steps/s per actor | updates/s | samples/s "
        "| weights latency ms (median, max) |"
    )
    print("|---|---|---|---|---|---|")
    for n in actors:
        port = _free_port()
        run_id = f"bench-system-{n}-{int(time.time())}"
        cmd = [sys.executable, "-m", "deploy.cli", "launch", "--preset", preset, "--task", task, "--actors", str(n),
               "--run-id", run_id, "--router-port", "0", "--dashboard-port", str(port),
               "--set", f"replay.zmq_endpoint=tcp://127.0.0.1:{_free_port()}", "--set", "launch.progress_every_s=0"]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        samples, latencies = [], []
        try:
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=5) as http:
                deadline = time.monotonic() + minutes * 60
                warm_until = time.monotonic() + 60
                while time.monotonic() < deadline:
                    time.sleep(5)
                    try:
                        snap = http.get("/api/status").json()
                    except (httpx.HTTPError, ValueError):
                        continue
                    roles = [r for r in snap["roles"] if r["alive"]]
                    learner = next((r["counters"] for r in roles if r["role"] == "learner"), {})
                    acting = [r["counters"] for r in roles if r["role"] == "actor"]
                    latencies += [c["weights_latency_s"] for c in acting if c.get("weights_latency_s")]
                    if time.monotonic() >= warm_until:
                        samples.append((time.monotonic(), sum(c.get("env_steps", 0) for c in acting),
                                        learner.get("updates", 0), learner.get("samples", 0)))
        finally:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
        if len(samples) < 2:
            print(f"| {n} | no data |")
            continue
        (t0, e0, u0, s0), (t1, e1, u1, s1) = samples[0], samples[-1]
        dt = t1 - t0
        lat = f"{1e3 * statistics.median(latencies):.0f}, {1e3 * max(latencies):.0f}" if latencies else "-"
        print(f"| {n} | {(e1 - e0) / dt:.2f} | {(e1 - e0) / dt / n:.2f} | {(u1 - u0) / dt:.2f} | "
              f"{(s1 - s0) / dt:.1f} | {lat} |", flush=True)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    d = sub.add_parser("decision", help="time one decision's parts in-process")
    d.add_argument("--task", default="reach_target", help="task whose scripted poses are executed")
    d.add_argument("--decisions", type=int, default=20, help="decisions timed per row")
    s = sub.add_parser("system", help="run the launcher and read throughput from the dashboard")
    s.add_argument("--actors", type=int, nargs="+", default=[1, 2], help="actor counts to compare")
    s.add_argument("--minutes", type=float, default=4.0, help="wall clock per actor count")
    s.add_argument("--preset", default="cpu-small", help="config preset")
    s.add_argument("--task", default="reach_target", help="task")
    args = parser.parse_args()
    if args.what == "decision":
        time_decisions(args.task, args.decisions)
    else:
        measure_system(args.actors, args.minutes, args.preset, args.task)
    return 0


if __name__ == "__main__":
    sys.exit(main())
