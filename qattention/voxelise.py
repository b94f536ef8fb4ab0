"""Batched voxelisation of fused point clouds into the 10-channel grid of spec §2, and index helpers.

Channels ``[mean x, mean y, mean z, mean r, mean g, mean b, i/V, j/V, k/V, occupancy]``;
spatial axes 0/1/2 = world x/y/z. Differences from the reference ``VoxelGrid``: any batch
size and point count (no pre-allocated index tensors), per-sample bounds always, and
non-finite points are dropped too. Points outside ``[min, max)`` are dropped, which is what
the reference's padding shell achieves.
"""

from __future__ import annotations

import torch

CHANNELS = 10


def voxel_resolution(bounds: torch.Tensor, voxel_size: int) -> torch.Tensor:
    """Edge length per axis [..., 3] of one voxel of ``bounds`` [..., 6]."""
    return (bounds[..., 3:] - bounds[..., :3]) / voxel_size


def point_to_voxel_index(points: torch.Tensor, bounds: torch.Tensor, voxel_size: int) -> torch.Tensor:
    """Voxel index [..., 3] (long) containing each point [..., 3] of ``bounds`` [..., 6].

    Clamped to ``[0, V-1]`` on both sides (the reference only clamps the top, spec §10.6,
    so a label below the bounds became an invalid negative index).
    """
    res = voxel_resolution(bounds, voxel_size)
    idx = torch.floor((points - bounds[..., :3]) / res)
    return idx.clamp(0, voxel_size - 1).long()


def voxel_centre(index: torch.Tensor, bounds: torch.Tensor, voxel_size: int) -> torch.Tensor:
    """World coordinate [..., 3] of the centre of voxel ``index`` [..., 3] (centre, not corner: DESIGN §4)."""
    res = voxel_resolution(bounds, voxel_size)
    return bounds[..., :3] + res * (index.to(res.dtype) + 0.5)


def child_bounds(centre: torch.Tensor, offset: float) -> torch.Tensor:
    """Bounds [..., 6] of the next depth's cube of half-width ``offset`` around ``centre`` [..., 3]."""
    return torch.cat([centre - offset, centre + offset], -1)


def flat_index(index: torch.Tensor, voxel_size: int) -> torch.Tensor:
    """[..., 3] voxel index -> flat index ``(i*V + j)*V + k``."""
    return (index[..., 0] * voxel_size + index[..., 1]) * voxel_size + index[..., 2]


def unflatten_index(flat: torch.Tensor, voxel_size: int) -> torch.Tensor:
    """Flat index -> [..., 3] voxel index."""
    v = voxel_size
    return torch.stack([flat // (v * v), (flat // v) % v, flat % v], -1)


def index_grid(voxel_size: int, device=None) -> torch.Tensor:
    """Normalised index channels [3, V, V, V] = ``(i/V, j/V, k/V)``."""
    r = torch.arange(voxel_size, device=device, dtype=torch.float32) / voxel_size
    return torch.stack(torch.meshgrid(r, r, r, indexing="ij"), 0)


def voxelise(points: torch.Tensor, features: torch.Tensor, bounds: torch.Tensor, voxel_size: int) -> torch.Tensor:
    """Scatter-mean points [B, N, 3] with features [B, N, 3] (rgb in [-1, 1]) into [B, 10, V, V, V].

    ``bounds`` is [B, 6] (or [6], shared). Empty voxels are zero except the index channels.
    """
    b, n, _ = points.shape
    v = voxel_size
    points = points.float()
    features = features.float()
    bounds = bounds.to(points).expand(b, 6) if bounds.dim() == 1 else bounds.to(points)
    lo = bounds[:, None, :3]
    res = voxel_resolution(bounds, v)[:, None, :]
    idx = torch.floor((points - lo) / res)
    valid = ((idx >= 0) & (idx < v)).all(-1) & torch.isfinite(points).all(-1) & torch.isfinite(features).all(-1)
    idx = idx.clamp(0, v - 1).long()
    flat = flat_index(idx, v) + torch.arange(b, device=points.device)[:, None] * v**3
    dump = b * v**3  # one extra row collects every dropped point
    flat = torch.where(valid, flat, torch.full_like(flat, dump))
    values = torch.cat([points, features, torch.ones_like(points[..., :1])], -1)
    values = torch.where(valid[..., None], values, torch.zeros_like(values))
    acc = torch.zeros(dump + 1, 7, device=points.device, dtype=torch.float32)
    acc.index_add_(0, flat.reshape(-1), values.reshape(-1, 7))
    acc = acc[:dump].view(b, v, v, v, 7).permute(0, 4, 1, 2, 3)
    count = acc[:, 6:7]
    mean = acc[:, :6] / count.clamp_min(1.0)
    occupancy = (count > 0).float()
    grid = index_grid(v, points.device).expand(b, 3, v, v, v)
    return torch.cat([mean, grid, occupancy], 1)
