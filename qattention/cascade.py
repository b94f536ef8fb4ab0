"""Coarse-to-fine acting (spec §4.2): depth 0 .. D-1, each voxelised around the previous choice.

``descend`` takes one Q-function per depth, ``(grid, proprio) -> (q_trans [B,V,V,V],
q_rot_grip [B, 3*bins+2] | None)``, so the same loop serves the networks and any analytic Q.
The final translation is the centre of the last chosen voxel; rotation/gripper come from the
last depth's head (greedy, or explored, see exploration.py). With a reachability test and
``top_k`` > 1, an unreachable choice is replaced by the best reachable candidate of the last
depth (reachability.py); with ``skip_repeats``, a choice that repeats the gripper's pose by the
best one that moves (repeats.py). Each depth's best voxels by Q come back too (``top_voxels``), for
whoever watches the decision (the live view); they never travel to the replay.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from .action_codec import bins_to_rotation, rotation_to_bins
from .batch import ObservationBatch
from .crop import gather_points
from .exploration import explore_rotation, explore_voxel
from .reachability import ReachabilityTest, candidate_pose, inside_workspace, ranked_candidates
from .repeats import CANDIDATES as MOVING_CANDIDATES
from .repeats import Held, moving_choice, repeats_pose
from .voxelise import child_bounds, unflatten_index, voxel_centre, voxelise

QFunction = Callable[[torch.Tensor, torch.Tensor], tuple]
#: Reachability candidates' rotations differ by at least this much per Euler axis (reachability.py).
REACH_SEPARATION_DEG = 30
#: Best voxels per depth kept in ``ActResult.top_voxels``: enough to see where the attention spreads.
TOP_VOXELS = 8


@dataclass
class ActResult:
    action: np.ndarray  #: float32 [B, 8] next-best pose: xyz, quat xyzw, gripper_open (0/1)
    voxel_indices: np.ndarray  #: int64 [B, D, 3] chosen voxel per depth
    attention_coordinates: np.ndarray  #: float32 [B, D, 3] centre of the chosen voxel per depth
    rot_grip_indices: np.ndarray  #: int64 [B, 4] Euler bins + gripper index
    bounds: np.ndarray  #: float32 [B, D, 6] the box each depth voxelised
    q_values: np.ndarray  #: float32 [B, D] Q of the chosen voxel per depth
    #: float32 [B, D, TOP_VOXELS, 4] each depth's best voxels by Q, best first: centre xyz, Q (the network's
    #: ranking: an explored or reachability-replaced choice may lie elsewhere)
    top_voxels: np.ndarray
    voxel_size: int  #: voxels per side of every depth's grid (a voxel's edge is its box's extent / voxel_size)
    reach_checks: np.ndarray | None = None  #: int64 [B] reachability tests run (None: acting without them)
    reach_replaced: np.ndarray | None = None  #: bool [B] the first choice was unreachable and a candidate replaced it
    #: bool [B] the choice repeated the gripper's pose and the best one that moves replaced it (None: rule off)
    repeat_skipped: np.ndarray | None = None
    #: float32 [B, 2] the last depth's gripper values, index 0 closed and 1 open (what a diagnosis of the grasp reads)
    gripper_q: np.ndarray | None = None

    def replay_elements(self) -> dict[str, np.ndarray]:
        """The named arrays to store with the observation (keys of ``TransitionBatch``)."""
        return {
            "voxel_indices": self.voxel_indices,
            "attention_coordinates": self.attention_coordinates,
            "rot_grip_indices": self.rot_grip_indices,
        }


def depth_grid(obs: ObservationBatch, config, centre: torch.Tensor | None, bounds: torch.Tensor) -> torch.Tensor:
    """The voxel grid one depth of the cascade sees [B, 10, V, V, V]: the points around ``centre``
    (an image crop, or every pixel at depth 0 where ``centre`` is None) voxelised in ``bounds`` [B, 6].

    Acting, the TD targets, the update and the dashboard's snapshot all look through this one
    function, so a depth sees the same grid wherever it is evaluated.
    """
    points, rgb = gather_points(obs, config.cameras, centre, config.image_crop)
    return voxelise(points, rgb, bounds, config.voxel_size)


def top_voxels(q_trans: torch.Tensor, bounds: torch.Tensor, voxel_size: int, k: int) -> torch.Tensor:
    """The ``k`` best voxels of ``q_trans`` [B, V, V, V] in ``bounds`` [B, 6], best first: [B, k, 4] centre xyz, Q."""
    q, flat = q_trans.reshape(q_trans.shape[0], -1).float().topk(min(k, voxel_size ** 3), dim=1)
    centres = voxel_centre(unflatten_index(flat, voxel_size), bounds[:, None], voxel_size)
    return torch.cat([centres.float(), q[..., None]], -1)


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
    reachable: ReachabilityTest | None = None,
    top_k: int = 0,
    skip_repeats: bool = False,
) -> ActResult:
    b, v = obs.size, config.voxel_size
    explore = explore and config.epsilon > 0
    proprio = obs.proprioception(config)
    bounds = workspace = obs.bounds(config.scene_bounds)
    centre = None
    idxs, coords, all_bounds, qs, tops = [], [], [], [], []
    for d in range(config.depths):
        q_trans, q_rg = q_functions[d](depth_grid(obs, config, centre, bounds), proprio)
        tops.append(top_voxels(q_trans, bounds, v, TOP_VOXELS))
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
    checks = replaced = skipped = None
    checking = reachable is not None and top_k > 1
    if checking or skip_repeats:
        held = rotation_to_bins(obs.gripper_pose[:, 3:7], config.rotation_resolution)

    def take(i: int, voxel: torch.Tensor, bins: torch.Tensor, gripper: int | None = None) -> None:
        """Sample ``i`` acts on another candidate of the last depth (idx, centre are the lists' last entries)."""
        idx[i], rot[i] = voxel, bins
        centre[i] = voxel_centre(idx[i], bounds[i], v)
        qs[-1][i] = q_trans[i, idx[i, 0], idx[i, 1], idx[i, 2]]
        action[i, :7] = torch.cat([centre[i].float(), bins_to_rotation(rot[i], config.rotation_resolution)])
        if gripper is not None:
            grip[i] = action[i, 7] = gripper

    if checking:
        checks, replaced = np.zeros(b, np.int64), np.zeros(b, bool)
        for i in range(b):
            checks[i], choice = _reachable_choice(action[i], q_trans[i], q_rot[i], bounds[i], workspace[i], held[i],
                                                  config, reachable, top_k)
            if choice is not None:
                replaced[i] = True
                take(i, *choice)
    if skip_repeats:
        skipped = np.zeros(b, bool)
        separation = max(1, REACH_SEPARATION_DEG // config.rotation_resolution)
        for i in range(b):
            now = Held(obs.gripper_pose[i, :3], held[i], float(obs.gripper_open[i]))
            if not repeats_pose(centre[i], rot[i], int(grip[i]), bounds[i], v, now):
                continue
            tests, choice = moving_choice(idx[i], rot[i], int(grip[i]), q_trans[i], q_rot[i], q_grip[i], bounds[i],
                                          workspace[i], now, config, separation, reachable if checking else None,
                                          max(top_k, MOVING_CANDIDATES))
            if checks is not None:
                checks[i] += tests
            if choice is not None:
                skipped[i] = True
                take(i, *choice)
    np_ = lambda t: t.detach().cpu().numpy()  # noqa: E731
    return ActResult(
        action=np_(action).astype(np.float32),
        voxel_indices=np_(torch.stack(idxs, 1)).astype(np.int64),
        attention_coordinates=np_(torch.stack(coords, 1)).astype(np.float32),
        rot_grip_indices=np_(torch.cat([rot, grip[:, None]], 1)).astype(np.int64),
        bounds=np_(torch.stack(all_bounds, 1)).astype(np.float32),
        q_values=np_(torch.stack(qs, 1).float()),
        top_voxels=np_(torch.stack(tops, 1)).astype(np.float32),
        voxel_size=v,
        reach_checks=checks,
        reach_replaced=replaced,
        repeat_skipped=skipped,
        gripper_q=np_(q_grip.float()),
    )


def _reachable_choice(action, q_trans, q_rot, bounds, workspace, held_rotation, config,
                      reachable: ReachabilityTest, top_k: int):
    """(tests run, None) if ``action`` is reachable, else the best reachable (voxel, bins) of the top-K.

    Candidates lie in the ``workspace`` and include the ``held_rotation`` (the gripper's
    current Euler bins) at the best voxel (reachability.py). When no candidate is reachable
    either, the first choice stands (the episode then ends on an unreachable pose, as in the
    reference).
    """
    if reachable(action.detach().cpu().numpy()):
        return 1, None
    checks, first = 1, action.detach().cpu()
    separation = max(1, REACH_SEPARATION_DEG // config.rotation_resolution)
    inside = inside_workspace(bounds, config.voxel_size, workspace)
    candidates = ranked_candidates(q_trans, q_rot, top_k, separation, inside=inside, fallback_rotation=held_rotation)
    for voxel, bins in zip(*candidates):
        pose = candidate_pose(voxel, bins, bounds, config).cpu()
        if torch.allclose(pose, first[:7]):
            continue  # the first choice itself: already known unreachable
        checks += 1
        if reachable(torch.cat([pose, first[7:]]).numpy()):
            return checks, (voxel, bins)
    return checks, None
