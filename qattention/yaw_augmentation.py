"""Yaw augmentation of demo rows: turn the scene about the vertical through the demo's next pose.

Ten demos show the rotation heads ten object yaws, too few to learn that the gripper's yaw
must follow the object's (pick_and_lift stalled at ~70 % with one yaw for every block,
BENCHMARKS.md). Turning a demo row's point clouds, its gripper pose and its action by the same
random yaw about the vertical line through the action's position gives a new, equally valid
demo: the target point stays put, so every translation label is unchanged, and the yaw label
turns with the scene. PerAct (Shridhar et al., 2022) augments its demos the same way; the
C2F-ARM reference does not (``demo_yaw_augmentation = 0``).

Cameras are left where they are, so the depth >= 1 image crop still picks the pixels around
the (unmoved) target and their points turn about it.
"""

from __future__ import annotations

import dataclasses

import torch

from .batch import ObservationBatch, TransitionBatch


def yaw_quaternion(angle: torch.Tensor) -> torch.Tensor:
    """Rotation about world z by ``angle`` (radians) [B] -> quaternion xyzw [B, 4]."""
    zero = torch.zeros_like(angle)
    return torch.stack([zero, zero, torch.sin(angle / 2), torch.cos(angle / 2)], -1)


def quaternion_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a * b`` of xyzw quaternions [..., 4] (``b`` first, then ``a``)."""
    ax, ay, az, aw = a.unbind(-1)
    bx, by, bz, bw = b.unbind(-1)
    return torch.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        -1,
    )


def turn_points(points: torch.Tensor, centre: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Points [B, ..., 3] turned by ``angle`` [B] (radians) about the vertical through ``centre`` [B, 3]."""
    shape = (-1,) + (1,) * (points.dim() - 2)
    c, s = torch.cos(angle).view(shape), torch.sin(angle).view(shape)
    o = centre.view(*shape, 3).to(points)
    x, y = points[..., 0] - o[..., 0], points[..., 1] - o[..., 1]
    return torch.stack([o[..., 0] + c * x - s * y, o[..., 1] + s * x + c * y, points[..., 2]], -1)


def turn_pose(pose: torch.Tensor, centre: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Poses [B, 7+] (xyz, quat xyzw, ...) turned about the vertical through ``centre``; extra columns kept."""
    xyz = turn_points(pose[:, :3], centre, angle)
    quat = quaternion_multiply(yaw_quaternion(angle).to(pose), pose[:, 3:7])
    return torch.cat([xyz, quat, pose[:, 7:]], 1)


def _turn_observation(obs: ObservationBatch, rows: torch.Tensor, centre, angle) -> ObservationBatch:
    keep = lambda new, old: torch.where(rows.view(-1, *(1,) * (old.dim() - 1)), new, old)  # noqa: E731
    return dataclasses.replace(
        obs,
        points={c: keep(turn_points(p, centre, angle), p) for c, p in obs.points.items()},
        gripper_pose=keep(turn_pose(obs.gripper_pose, centre, angle), obs.gripper_pose),
    )


def augment_yaw(
    batch: TransitionBatch, max_degrees: float, generator: torch.Generator | None = None
) -> TransitionBatch:
    """The batch with every demo row turned by its own uniform yaw in +-``max_degrees`` (agent rows untouched)."""
    if max_degrees <= 0 or not bool(batch.is_demo.any()):
        return batch
    u = torch.rand(batch.size, generator=generator).to(batch.action.device)
    return turn_demo_rows(batch, (u * 2 - 1) * max_degrees)


def turn_demo_rows(batch: TransitionBatch, degrees: torch.Tensor) -> TransitionBatch:
    """Demo rows turned by ``degrees`` [B] about the vertical through their action's position.

    Agent rows are returned bit-identical: their act-time labels describe the scene as it was.
    Both observations of a row turn alike, so the TD target sees the same turned world.
    """
    rows = batch.is_demo
    angle = torch.deg2rad(degrees.to(batch.action)) * rows.float()
    centre = batch.action[:, :3]
    action = torch.where(rows[:, None], turn_pose(batch.action, centre, angle), batch.action)
    return dataclasses.replace(
        batch,
        obs=_turn_observation(batch.obs, rows, centre, angle),
        next_obs=_turn_observation(batch.next_obs, rows, centre, angle),
        action=action,
    )
