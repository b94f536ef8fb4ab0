"""Continuous next-best pose <-> discrete labels (spec §4).

Labels: per-depth voxel indices [B, D, 3], rotation bins [B, 3] (scipy extrinsic 'xyz' Euler,
+180 deg, round-half-even, wrap 72 -> 0) and gripper index [B] (1 open, 0 closed).
Deviations (DESIGN §4): the next cube is centred on the voxel *centre* (reference: corner,
spec §10.2), and with crop augmentation the stored attention coordinate is the shifted
centre actually used for the next depth's bounds (spec §10.1), so labels always agree with
the bounds rebuilt from them. Labelling is meant to run at sample time in the learner, so
each sample of a demo transition gets fresh crop noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .rotation import euler_to_quaternion, quaternion_to_euler
from .voxelise import child_bounds, point_to_voxel_index, voxel_centre


@dataclass
class ActionLabels:
    voxel_indices: torch.Tensor  #: long [B, D, 3], the voxel of each depth
    coordinates: torch.Tensor  #: float [B, D, 3], centre of the next cube (d < D-1) / of the final voxel (d = D-1)
    bounds: torch.Tensor  #: float [B, D, 6], the bounds each depth was labelled in
    rotation: torch.Tensor  #: long [B, 3], Euler bins
    gripper: torch.Tensor  #: long [B], 1 open / 0 closed

    @property
    def rot_grip(self) -> torch.Tensor:
        """long [B, 4] = (rx, ry, rz, gripper), the reference's ``rot_grip_action_indicies``."""
        return torch.cat([self.rotation, self.gripper[:, None]], 1)


def rotation_to_bins(quaternion: torch.Tensor, resolution: int) -> torch.Tensor:
    """Quaternion xyzw [..., 4] -> Euler bins [..., 3] (long); pitch only reaches bins 18..54 at 5 deg."""
    q = quaternion / quaternion.norm(dim=-1, keepdim=True)
    q = torch.where(q[..., 3:4] < 0, -q, q)  # reference flips w<0; no effect on Euler
    e = quaternion_to_euler(q.double()) + 180.0
    idx = torch.round(e / resolution).long()  # torch.round is half-to-even like numpy
    return idx % (360 // resolution)


def bins_to_euler(bins: torch.Tensor, resolution: int) -> torch.Tensor:
    """Euler bins [..., 3] -> degrees [..., 3] (bin centre)."""
    return bins.double() * resolution - 180.0


def bins_to_rotation(bins: torch.Tensor, resolution: int) -> torch.Tensor:
    """Euler bins [..., 3] -> quaternion xyzw [..., 4] (float32)."""
    return euler_to_quaternion(bins_to_euler(bins, resolution)).float()


def crop_noise(batch: int, config, generator: torch.Generator | None = None, device=None) -> torch.Tensor:
    """Uniform shifts [B, D-1, 3] in +-crop_shift*offset for the cubes of depths 1..D-1 (spec §6.4)."""
    u = torch.rand(batch, max(config.depths - 1, 0), 3, generator=generator, device=device)
    scale = torch.tensor([config.offset(d) for d in range(1, config.depths)], device=device)
    return (u * 2 - 1) * config.crop_shift * scale[None, :, None]


def encode_translation(xyz: torch.Tensor, scene_bounds: torch.Tensor, config, noise: torch.Tensor | None = None):
    """xyz [B, 3] -> (voxel indices [B, D, 3], coordinates [B, D, 3], bounds [B, D, 6]).

    ``noise`` [B, D-1, 3] shifts the centre of each finer cube (crop augmentation); rows where it
    is zero are labelled exactly as the cascade would act.
    """
    bounds = scene_bounds.to(xyz).expand(xyz.shape[0], 6)
    idx, coords, all_bounds = [], [], []
    for d in range(config.depths):
        i = point_to_voxel_index(xyz, bounds, config.voxel_size)
        c = voxel_centre(i, bounds, config.voxel_size)
        if d < config.depths - 1 and noise is not None:
            c = c + noise[:, d].to(c)
        idx.append(i)
        coords.append(c)
        all_bounds.append(bounds)
        if d < config.depths - 1:
            bounds = child_bounds(c, config.offset(d + 1))
    return torch.stack(idx, 1), torch.stack(coords, 1), torch.stack(all_bounds, 1)


def decode_translation(voxel_indices: torch.Tensor, scene_bounds: torch.Tensor, config) -> torch.Tensor:
    """Per-depth voxel indices [B, D, 3] -> xyz [B, 3]: centre of the last voxel, cubes centred on voxel centres."""
    bounds = scene_bounds.float().expand(voxel_indices.shape[0], 6)
    for d in range(config.depths):
        c = voxel_centre(voxel_indices[:, d], bounds, config.voxel_size)
        if d < config.depths - 1:
            bounds = child_bounds(c, config.offset(d + 1))
    return c


def encode_action(
    action: torch.Tensor, scene_bounds: torch.Tensor, config, noise: torch.Tensor | None = None
) -> ActionLabels:
    """Executed pose [B, 8] (xyz, quat xyzw, gripper_open) -> labels."""
    idx, coords, bounds = encode_translation(action[:, :3].float(), scene_bounds, config, noise)
    rot = rotation_to_bins(action[:, 3:7], config.rotation_resolution)
    grip = (action[:, 7] > 0.5).long()
    return ActionLabels(idx, coords, bounds, rot, grip)


def decode_action(
    voxel_indices: torch.Tensor, rot_grip: torch.Tensor, scene_bounds: torch.Tensor, config
) -> torch.Tensor:
    """Labels -> pose [B, 8] float32 (xyz, quat xyzw, gripper 0/1)."""
    xyz = decode_translation(voxel_indices, scene_bounds, config)
    quat = bins_to_rotation(rot_grip[:, :3], config.rotation_resolution)
    return torch.cat([xyz.float(), quat, rot_grip[:, 3:4].float()], 1)
