"""Scripted demonstrations: run a task's waypoints through the actor's own control agent, record every
control step, keep the successful ones (a failed seed is retried with the next seed and counted)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from protocol.episode_file import Demo, write_demo
from actors.sim.config import SimConfig
from actors.panda_env import PandaEnv
from actors.sim.tasks import make_task


def record_demo(env: PandaEnv, seed: int) -> Demo:
    """One scripted episode; ``waypoint_frames`` marks where each waypoint's motion (and gripper) ended."""
    frames = [env.reset(seed)]
    ends: list[int] = []
    result = None
    for wp in env.demo_waypoints():
        result = env.step(wp.action(), record=frames.append, linear=wp.linear)
        if result.unreachable:
            break
        ends.append(len(frames) - 1)
    success = bool(result is not None and result.success and len(ends) == len(env.demo_waypoints()))
    return Demo(task=env.config.task, seed=seed, success=success, observations=frames, waypoint_frames=ends,
                control_hz=env.config.control_hz)


@dataclass
class DemoSummary:
    """What a generation run did."""

    task: str
    written: list[str] = field(default_factory=list)  #: demo files, one per successful episode
    seeds: list[int] = field(default_factory=list)  #: the seed of each written demo
    failed_seeds: list[int] = field(default_factory=list)  #: seeds whose scripted demo failed (skipped)
    seconds: float = 0.0
    bytes: int = 0


def generate_demos(task: str, episodes: int, seed: int, out_dir: str | Path,
                   cameras: tuple[str, ...] = ("front", "left_shoulder", "right_shoulder", "wrist"),
                   image_size: int = 128, progress: bool = True, max_failures: int | None = None) -> DemoSummary:
    """Write ``episodes`` successful demos of ``task`` to ``out_dir`` as ``<task>_seed<S>.mcap``."""
    make_task(task)  # unknown names fail here, listing the known ones
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    max_failures = episodes * 2 + 5 if max_failures is None else max_failures
    summary = DemoSummary(task)
    env = PandaEnv(SimConfig(task=task, cameras=tuple(cameras), image_size=image_size, seed=seed))
    start, s = time.perf_counter(), seed
    bar = tqdm(total=episodes, desc=f"demos {task}", unit="demo", disable=not progress)
    try:
        while len(summary.written) < episodes:
            if len(summary.failed_seeds) > max_failures:
                raise RuntimeError(f"{task}: {len(summary.failed_seeds)} scripted demos failed, giving up")
            demo = record_demo(env, s)
            if demo.success:
                demo.attempts = len(summary.failed_seeds) + 1
                path = out / f"{task}_seed{s:06d}.mcap"
                summary.bytes += write_demo(path, demo)
                summary.written.append(str(path))
                summary.seeds.append(s)
                bar.update(1)
            else:
                summary.failed_seeds.append(s)
            bar.set_postfix(failed=len(summary.failed_seeds))
            s += 1
    finally:
        bar.close()
        env.close()
    summary.seconds = time.perf_counter() - start
    return summary
