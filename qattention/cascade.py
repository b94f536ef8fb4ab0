"""Coarse-to-fine acting (spec §4.2): depth 0 .. D-1, each voxelised around the previous choice.

``descend`` takes one Q-function per depth, ``(grid, proprio) -> (q_trans [B,V,V,V],
q_rot_grip [B, 3*bins+2] | None)``, so the same loop serves the networks and any analytic Q.
The final translation is the centre of the last chosen voxel; rotation/gripper come from the
last depth's head (greedy, or explored, see exploration.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from .action_codec import bins_to_rotation
from .batch import ObservationBatch
from .crop import gather_points
from .exploration import explore_rotation, explore_voxel
from .voxelise import child_bounds, unflatten_index, voxel_centre, voxelise

QFunction = Callable[[torch.Tensor, torch.Tensor], tuple]


@dataclass
class ActResult:
    action: np.ndarray  #: float32 [B, 8] next-best pose: xyz, quat xyzw, gripper_open (0/1)
    voxel_indices: np.ndarray  #: int64 [B, D, 3] chosen voxel per depth
    attention_coordinates: np.ndarray  #: float32 [B, D, 3] centre of the chosen voxel per depth
    rot_grip_indices: np.ndarray  #: int64 [B, 4] Euler bins + gripper index
    bounds: np.ndarray  #: float32 [B, D, 6] the box each depth voxelised
    q_values: np.ndarray  #: float32 [B, D] Q of the chosen voxel per depth

    def replay_elements(self) -> dict[str, np.ndarray]:
        """The named arrays to store with the observation (keys of ``TransitionBatch``)."""
        return {
            "voxel_indices": self.voxel_indices,
            "attention_coordinates": self.attention_coordinates,
            "rot_grip_indices": self.rot_grip_indices,
        }


def split_rot_grip(q_rot_grip: torch.Tensor, bins: int):
    """[B, 3*bins+2] -> rotation Q [B, 3, bins], gripper Q [B, 2]."""
    return q_rot_grip[:, : 3 * bins].reshape(-1, 3, bins), q_rot_grip[:, 3 * bins :]


@torch.no_grad()
def descend(
    obs: ObservationBatch,
    q_functions: Sequence[QFunction],
    config,
    explore: bool = False,
    generator: torch.Generator | None = None,
) -> ActResult:
    b, v = obs.size, config.voxel_size
    explore = explore and config.epsilon > 0
    proprio = obs.proprioception(config.episode_length)
    bounds = obs.bounds(config.scene_bounds)
    centre = None
    idxs, coords, all_bounds, qs = [], [], [], []
    for d in range(config.depths):
        points, rgb = gather_points(obs, config.cameras, centre, config.image_crop)
        grid = voxelise(points, rgb, bounds, v)
        q_trans, q_rg = q_functions[d](grid, proprio)
        idx = unflatten_index(q_trans.reshape(b, -1).argmax(1), v)
        if explore:
            idx = explore_voxel(idx, config, generator)
        qs.append(q_trans[torch.arange(b, device=idx.device), idx[:, 0], idx[:, 1], idx[:, 2]])
        centre = voxel_centre(idx, bounds, v)
        idxs.append(idx)
        coords.append(centre)
        all_bounds.append(bounds)
        if d < config.depths - 1:
            bounds = child_bounds(centre, config.offset(d + 1))
    q_rot, q_grip = split_rot_grip(q_rg, config.rotation_bins)
    rot, grip = q_rot.argmax(-1), q_grip.argmax(-1)
    if explore:
        rot, grip = explore_rotation(rot, grip, config, generator)
    quat = bins_to_rotation(rot, config.rotation_resolution)
    action = torch.cat([centre.float(), quat, grip[:, None].float()], 1)
    np_ = lambda t: t.detach().cpu().numpy()  # noqa: E731
    return ActResult(
        action=np_(action).astype(np.float32),
        voxel_indices=np_(torch.stack(idxs, 1)).astype(np.int64),
        attention_coordinates=np_(torch.stack(coords, 1)).astype(np.float32),
        rot_grip_indices=np_(torch.cat([rot, grip[:, None]], 1)).astype(np.int64),
        bounds=np_(torch.stack(all_bounds, 1)).astype(np.float32),
        q_values=np_(torch.stack(qs, 1).float()),
    )
