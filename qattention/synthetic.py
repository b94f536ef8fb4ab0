"""A tiny ray-cast scene (table plane + coloured sphere) that yields replay-style arrays.

For tests, benchmarks and smoke runs without a simulator: cameras follow the protocol's
conventions (world-frame points aligned with pixels, OpenCV pinhole K, camera-to-world
extrinsics), so projection, cropping and voxelisation see realistic inputs.
"""

from __future__ import annotations

import numpy as np
import torch

from protocol import transition as tr

from .rotation import euler_to_quaternion

CAMERA_POSITIONS = {
    "front": (1.6, 0.0, 1.6),
    "left_shoulder": (0.2, 0.9, 1.7),
    "right_shoulder": (0.2, -0.9, 1.7),
    "wrist": (0.3, 0.0, 1.5),
    "overhead": (0.25, 0.01, 2.3),
}


def look_at(position, target) -> np.ndarray:
    """Camera-to-world [4, 4] (OpenCV: +x right, +y down, +z forward) at ``position`` looking at ``target``."""
    p, t = np.asarray(position, np.float64), np.asarray(target, np.float64)
    f = (t - p) / np.linalg.norm(t - p)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, d, f, p
    return m


def intrinsics(resolution: int, fov_deg: float = 60.0) -> np.ndarray:
    f = resolution / (2 * np.tan(np.deg2rad(fov_deg) / 2))
    return np.array([[f, 0, resolution / 2], [0, f, resolution / 2], [0, 0, 1]], np.float64)


def render(extrinsics, k, resolution, table_z, sphere_centre, sphere_radius):
    """Ray-cast points [H, W, 3] and rgb [H, W, 3] of the table plane and a red sphere."""
    v, u = np.meshgrid(np.arange(resolution) + 0.5, np.arange(resolution) + 0.5, indexing="ij")
    rays_cam = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u)], -1)
    rays = rays_cam @ extrinsics[:3, :3].T
    o = extrinsics[:3, 3]
    t_plane = (table_z - o[2]) / np.where(np.abs(rays[..., 2]) < 1e-9, -1e-9, rays[..., 2])
    t_plane = np.where(t_plane > 0, t_plane, 1e3)
    oc = o - sphere_centre
    bq = rays @ oc
    aq = (rays * rays).sum(-1)
    disc = bq**2 - aq * (oc @ oc - sphere_radius**2)
    t_sphere = np.where(disc > 0, (-bq - np.sqrt(np.maximum(disc, 0))) / aq, 1e3)
    hit_sphere = (t_sphere > 0) & (t_sphere < t_plane)
    t = np.where(hit_sphere, t_sphere, t_plane)
    points = o + rays * t[..., None]
    rgb = np.where(hit_sphere[..., None], [200, 30, 30], [120, 110, 100]).astype(np.uint8)
    return points.astype(np.float32), rgb


def observation_arrays(
    batch: int,
    cameras=("front",),
    resolution: int = 128,
    scene_bounds=(-0.3, -0.5, 0.6, 0.7, 0.5, 1.6),
    targets: np.ndarray | None = None,
    seed: int = 0,
    suffix: str = "",
) -> dict[str, np.ndarray]:
    """Observation arrays (protocol names) of ``batch`` scenes; sphere centres ``targets`` [B, 3] or random."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(scene_bounds[:3]), np.asarray(scene_bounds[3:])
    table_z = lo[2] + 0.1 * (hi[2] - lo[2])
    if targets is None:
        targets = lo + (hi - lo) * rng.uniform([0.2, 0.2, 0.15], [0.8, 0.8, 0.5], (batch, 3))
    out: dict[str, np.ndarray] = {}
    k = intrinsics(resolution)
    centre = (lo + hi) / 2
    for c in cameras:
        ext = look_at(centre + (np.asarray(CAMERA_POSITIONS[c]) - np.array([0.2, 0.0, 1.1])), centre)
        pts, rgb = zip(*(render(ext, k, resolution, table_z, targets[i], 0.05) for i in range(batch)))
        out[f"{c}_points{suffix}"] = np.stack(pts)
        out[f"{c}_rgb{suffix}"] = np.stack(rgb)
        out[f"{c}_intrinsics{suffix}"] = np.broadcast_to(k.astype(np.float32), (batch, 3, 3)).copy()
        out[f"{c}_extrinsics{suffix}"] = np.broadcast_to(ext.astype(np.float32), (batch, 4, 4)).copy()
    euler = rng.uniform([-180, -60, -180], [180, 60, 180], (batch, 3))
    quat = euler_to_quaternion(torch.as_tensor(euler)).numpy().astype(np.float32)
    out[f"gripper_pose{suffix}"] = np.concatenate([targets.astype(np.float32), quat], 1)
    out[f"gripper_open{suffix}"] = rng.integers(0, 2, batch).astype(np.float32)
    out[f"finger_positions{suffix}"] = rng.uniform(0, 0.04, (batch, 2)).astype(np.float32)
    out[f"joint_positions{suffix}"] = rng.normal(size=(batch, 7)).astype(np.float32)
    out[f"joint_velocities{suffix}"] = np.zeros((batch, 7), np.float32)
    out[f"step{suffix}"] = rng.integers(0, 9, batch).astype(np.int32)
    return out


def transition_arrays(
    batch: int, cameras=("front",), resolution: int = 128, seed: int = 0, **kw
) -> dict[str, np.ndarray]:
    """A replay-style transition batch: the action is a pose at the sphere (reward 100, terminal) in
    half the rows, elsewhere a random pose with reward 0."""
    rng = np.random.default_rng(seed + 1)
    out = observation_arrays(batch, cameras, resolution, seed=seed, **kw)
    out.update(observation_arrays(batch, cameras, resolution, seed=seed + 2, suffix=tr.NEXT, **kw))
    success = np.arange(batch) % 2 == 0
    action = np.concatenate([out["gripper_pose"], rng.integers(0, 2, (batch, 1)).astype(np.float32)], 1)
    bounds = np.asarray(kw.get("scene_bounds", (-0.3, -0.5, 0.6, 0.7, 0.5, 1.6)))
    random_xyz = rng.uniform(bounds[:3], bounds[3:], (batch, 3))
    action[~success, :3] = random_xyz[~success]
    out[tr.ACTION] = action.astype(np.float32)
    out[tr.REWARD] = np.where(success, 100.0, 0.0).astype(np.float32)
    out[tr.TERMINAL] = success.copy()
    out[tr.IS_DEMO] = success.copy()
    out[tr.WEIGHTS] = np.ones(batch, np.float32)
    out[tr.POLICY_VERSION] = np.zeros(batch, np.int64)
    return out
