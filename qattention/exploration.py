"""Epsilon exploration over voxels and rotation/gripper bins.

The reference forces greedy acting (spec §6.5; its dormant gaussian branch also crashed on
GPU). Here, with probability ``epsilon`` independently per depth, per rotation axis and for
the gripper, the greedy choice is replaced: 'gaussian' jitters it by round(N(0, sigma))
voxels / bins (voxels clamped to the grid, roll/yaw wrapped, pitch kept in [-90, 90]);
'uniform' draws any voxel / bin. Noise is drawn on CPU from the caller's generator, then moved.
"""

from __future__ import annotations

import torch


def _rand(shape, generator, device):
    return torch.rand(shape, generator=generator).to(device)


def _randn(shape, generator, device):
    return torch.randn(shape, generator=generator).to(device)


def explore_voxel(index: torch.Tensor, config, generator: torch.Generator | None = None) -> torch.Tensor:
    """Greedy voxel [B, 3] -> explored voxel [B, 3]."""
    b, v, dev = index.shape[0], config.voxel_size, index.device
    pick = _rand((b, 1), generator, dev) < config.epsilon
    if config.exploration == "uniform":
        new = torch.randint(0, v, (b, 3), generator=generator).to(dev)
    else:
        new = index + torch.round(_randn((b, 3), generator, dev) * config.explore_voxel_sigma).long()
    return torch.where(pick, new.clamp(0, v - 1), index)


def explore_rotation(rotation: torch.Tensor, gripper: torch.Tensor, config, generator: torch.Generator | None = None):
    """Greedy Euler bins [B, 3] and gripper [B] -> explored ones."""
    b, n, dev = rotation.shape[0], config.rotation_bins, rotation.device
    lo, hi = n // 4, 3 * n // 4  # pitch bins of [-90, 90] deg
    pick = _rand((b, 3), generator, dev) < config.epsilon
    if config.exploration == "uniform":
        new = torch.randint(0, n, (b, 3), generator=generator).to(dev)
        new[:, 1] = torch.randint(lo, hi + 1, (b,), generator=generator).to(dev)
    else:
        jittered = rotation + torch.round(_randn((b, 3), generator, dev) * config.explore_rotation_sigma).long()
        new = jittered % n
        new[:, 1] = jittered[:, 1].clamp(lo, hi)
    rotation = torch.where(pick, new, rotation)
    flip = _rand((b,), generator, dev) < config.epsilon
    gripper = torch.where(flip, 1 - gripper, gripper)
    return rotation, gripper
