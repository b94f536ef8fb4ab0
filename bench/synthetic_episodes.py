"""The one synthetic episode factory of the tests and the benchmarks.

``synthetic_episode(actor_id, episode_id, ...)`` is deterministic in its arguments, so a test
can rebuild any episode to compare a sampled batch bit for bit. Every observation carries
``extra_tag`` int64 [3] = (crc32(actor_id), episode_id, t) to find its source.

It lives in bench/ (not in the shipped packages, nor in tests/, which benchmarks do not
import): benchmarks import it as a sibling (``from synthetic_episodes import ...``), the tests
through pytest's ``pythonpath`` (pyproject.toml).
"""
from __future__ import annotations

import zlib

import numpy as np

from protocol.episode import Episode


def actor_tag(actor_id: str) -> int:
    return zlib.crc32(actor_id.encode())


def synthetic_episode(
    actor_id: str = "actor-0",
    episode_id: int = 0,
    steps: int = 10,
    cameras: tuple[str, ...] = ("front",),
    size: int = 128,
    points_dtype=np.float16,
    is_demo: bool = False,
    timeout: bool = False,
    task: str = "reach_target",
    structured: bool = True,
) -> Episode:
    """A valid episode with plausible image statistics (smooth shapes, not white noise, when
    ``structured``), so compression benchmarks are not trivially pessimistic."""
    seed = (actor_tag(actor_id) * 1_000_003 + episode_id) % (2**63)
    rng = np.random.default_rng(seed)
    n = steps + 1
    obs: dict[str, np.ndarray] = {}
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / max(1, size - 1)
    for ci, cam in enumerate(cameras):
        if structured:
            rgb = np.empty((n, size, size, 3), np.uint8)
            pts = np.empty((n, size, size, 3), np.float32)
            for t in range(n):
                base = np.stack([xx, yy, 0.5 * (xx + yy)], -1) * 180 + 30
                cy, cx = rng.uniform(0.2, 0.8, 2)
                blob = ((xx - cx) ** 2 + (yy - cy) ** 2) < 0.02
                base[blob] = rng.uniform(0, 255, 3)
                rgb[t] = (base + rng.integers(0, 4, (size, size, 3))).clip(0, 255)
                depth = 1.0 + 0.3 * yy + 0.1 * blob
                pts[t] = np.stack([xx - 0.5, yy - 0.5, depth], -1) + ci
        else:
            rgb = rng.integers(0, 256, (n, size, size, 3), dtype=np.uint8)
            pts = rng.standard_normal((n, size, size, 3)).astype(np.float32)
        obs[f"{cam}_rgb"] = rgb
        obs[f"{cam}_points"] = pts.astype(points_dtype)
        obs[f"{cam}_intrinsics"] = np.tile(np.eye(3, dtype=np.float32) * (ci + 1), (n, 1, 1))
        obs[f"{cam}_extrinsics"] = rng.standard_normal((n, 4, 4)).astype(np.float32)
    obs["gripper_pose"] = rng.standard_normal((n, 7)).astype(np.float32)
    obs["gripper_open"] = rng.integers(0, 2, n).astype(np.float32)
    obs["finger_positions"] = rng.uniform(0, 0.04, (n, 2)).astype(np.float32)
    obs["joint_positions"] = rng.standard_normal((n, 7)).astype(np.float32)
    obs["joint_velocities"] = rng.standard_normal((n, 7)).astype(np.float32)
    obs["step"] = np.arange(n, dtype=np.int32)
    obs["extra_tag"] = np.stack(
        [np.full(n, actor_tag(actor_id)), np.full(n, episode_id), np.arange(n)], -1
    ).astype(np.int64)
    terminals = np.zeros(steps, bool)
    terminals[-1] = True
    rewards = np.zeros(steps, np.float32)
    rewards[-1] = 0.0 if timeout else 100.0
    return Episode(
        actor_id=actor_id,
        episode_id=episode_id,
        task=task,
        seed=int(seed % (2**31)),
        is_demo=is_demo,
        success=not timeout,
        timeout=timeout,
        observations=obs,
        actions=rng.standard_normal((steps, 8)).astype(np.float32),
        rewards=rewards,
        terminals=terminals,
        policy_versions=np.full(steps, -1 if is_demo else episode_id // 3, np.int64),
        info={"source": "synthetic"},
    )
