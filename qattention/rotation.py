"""Quaternion (xyzw) <-> Euler angles, scipy's extrinsic ``'xyz'`` convention, in torch.

``R = Rz(gamma) @ Ry(beta) @ Rx(alpha)``; ``beta`` (pitch) lies in [-90, 90] deg. At gimbal
lock the third angle is set to 0, as scipy does. Written here because scipy is not a dependency.
"""

from __future__ import annotations

import torch


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternion xyzw [..., 4] -> rotation matrix [..., 3, 3] (normalises first)."""
    q = q / q.norm(dim=-1, keepdim=True)
    x, y, z, w = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        -1,
    ).reshape(*q.shape[:-1], 3, 3)


def matrix_to_euler(m: torch.Tensor) -> torch.Tensor:
    """Rotation matrix [..., 3, 3] -> extrinsic xyz Euler angles [..., 3] in degrees."""
    r20 = m[..., 2, 0].clamp(-1.0, 1.0)
    beta = torch.asin(-r20)
    alpha = torch.atan2(m[..., 2, 1], m[..., 2, 2])
    gamma = torch.atan2(m[..., 1, 0], m[..., 0, 0])
    locked = r20.abs() > 1.0 - 1e-7
    alpha = torch.where(locked, torch.atan2(-r20 * m[..., 0, 1], m[..., 1, 1]), alpha)
    gamma = torch.where(locked, torch.zeros_like(gamma), gamma)
    return torch.rad2deg(torch.stack([alpha, beta, gamma], -1))


def quaternion_to_euler(q: torch.Tensor) -> torch.Tensor:
    """Quaternion xyzw [..., 4] -> extrinsic xyz Euler degrees [..., 3] (scipy ``as_euler('xyz', degrees=True)``)."""
    return matrix_to_euler(quaternion_to_matrix(q))


def euler_to_quaternion(e: torch.Tensor) -> torch.Tensor:
    """Extrinsic xyz Euler degrees [..., 3] -> quaternion xyzw [..., 4] with w >= 0."""
    h = torch.deg2rad(e) / 2
    cx, cy, cz = torch.cos(h).unbind(-1)
    sx, sy, sz = torch.sin(h).unbind(-1)
    q = torch.stack(
        [
            cz * cy * sx - sz * sy * cx,
            cz * sy * cx + sz * cy * sx,
            sz * cy * cx - cz * sy * sx,
            cz * cy * cx + sz * sy * sx,
        ],
        -1,
    )
    return torch.where(q[..., 3:4] < 0, -q, q)
