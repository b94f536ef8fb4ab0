"""Reachability-aware acting: the best-Q next-best pose among the top-K that the arm can reach.

The cascade picks every head's argmax on its own, so nothing stops it from asking for a
gripper orientation the arm cannot take at that point; the reference then ends the episode
on an unreachable pose (reward 0), and early in training most exploring episodes end that
way (89 % on pick_and_lift, BENCHMARKS.md). Given a cheap reachability test from the control
agent (IK only, no planning), the cascade can instead keep its choice when it is reachable
and otherwise take the best candidate of the last depth that is: other rotations at the
chosen voxel, other voxels with the chosen rotation, ranked by ``Q_trans(voxel) + mean over
axes of Q_rot(bin)`` (every head regresses the same TD target, so their values share one
scale). K <= 1 (off) reproduces the reference.

Two cheap facts narrow the candidates before any IK runs. Voxels of the last depth's cube
that lie outside the workspace are never candidates (the child cube of a voxel near the
scene's edge sticks out of it; measured: about half the unreachable ends of early push_button
exploration). And the gripper's current orientation is always among the candidates, at the
best voxel: an untrained rotation head's top bins are often all orientations the arm cannot
take there, while the one it holds now usually can be.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from .action_codec import bins_to_rotation
from .voxelise import unflatten_index, voxel_centre

#: ``reachable(action [8]) -> bool``: can the arm take this next-best pose (xyz, quat xyzw, gripper)?
ReachabilityTest = Callable[[np.ndarray], bool]


def candidate_pose(voxel: torch.Tensor, bins: torch.Tensor, bounds: torch.Tensor, config) -> torch.Tensor:
    """A last-depth candidate's pose [7] (xyz, quat xyzw): the centre of ``voxel`` in the cube ``bounds``, the
    rotation of its Euler ``bins``; what the reachability test is asked about, without the gripper."""
    return torch.cat([voxel_centre(voxel, bounds, config.voxel_size).float(),
                      bins_to_rotation(bins, config.rotation_resolution).float()])


def distinct_top(values: torch.Tensor, m: int, separation: int) -> torch.Tensor:
    """Indices of the ``m`` best bins of a circular axis ``values`` [bins], each ``separation`` bins
    from every better one (greedy non-maximum suppression; the argmax comes first).

    Neighbouring bins are 5 degrees apart: when one pose is out of the arm's reach its
    neighbours usually are too, so candidates that differ by a bin or two are wasted tests.
    """
    bins = values.shape[0]
    order = values.argsort(descending=True).tolist()
    chosen: list[int] = []
    for b in order:
        if all(min(abs(b - c), bins - abs(b - c)) >= separation for c in chosen):
            chosen.append(b)
            if len(chosen) == m:
                break
    return torch.tensor(chosen, dtype=torch.long, device=values.device)


def top_rotations(q_rot: torch.Tensor, k: int, separation: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` best Euler-bin triplets of ``q_rot`` [3, bins] whose bins per axis are at least
    ``separation`` apart: bins [k, 3] and their mean Q [k]."""
    m = min(k, q_rot.shape[1])
    per_axis = [distinct_top(q_rot[axis], m, separation) for axis in range(3)]
    n = [len(b) for b in per_axis]
    values = [q_rot[axis, b] for axis, b in enumerate(per_axis)]
    score = (values[0][:, None, None] + values[1][None, :, None] + values[2][None, None, :]) / 3
    best = score.reshape(-1).topk(min(k, score.numel()))
    i, j, m = np.unravel_index(best.indices.cpu().numpy(), n)
    return torch.stack([per_axis[0][i], per_axis[1][j], per_axis[2][m]], 1), best.values


def inside_workspace(bounds: torch.Tensor, voxel_size: int, workspace: torch.Tensor) -> torch.Tensor:
    """bool [V, V, V]: which voxel centres of the cube ``bounds`` [6] lie in ``workspace`` [6]."""
    r = torch.arange(voxel_size, device=bounds.device)
    index = torch.stack(torch.meshgrid(r, r, r, indexing="ij"), -1)
    centre = voxel_centre(index, bounds, voxel_size)
    return ((centre >= workspace[:3]) & (centre <= workspace[3:])).all(-1)


def ranked_candidates(q_trans: torch.Tensor, q_rot: torch.Tensor, k: int, separation: int = 1,
                      inside: torch.Tensor | None = None,
                      fallback_rotation: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Up to ``k`` (voxel, rotation) candidates of one sample, best joint Q first.

    ``q_trans`` [V, V, V] is the last depth's translation Q, ``q_rot`` [3, bins] its rotation Q.
    A pose is out of reach either for its orientation or for its position, so the candidates
    are the best rotations (bins at least ``separation`` apart per axis) at the best voxel,
    and the best voxels with the best rotation. ``inside`` [V, V, V] (bool) leaves out voxels
    outside the workspace; ``fallback_rotation`` [3] (bins, e.g. the gripper's current
    orientation) takes the last place at the best voxel unless it is a candidate already.
    Returns voxel indices [n, 3] and Euler bins [n, 3], n <= k (n = 0: no voxel inside).
    """
    flat_q = q_trans.reshape(-1)
    if inside is not None:
        flat_q = flat_q.masked_fill(~inside.reshape(-1), float("-inf"))
    n_voxels = int(torch.isfinite(flat_q).sum()) if inside is not None else flat_q.numel()
    if n_voxels == 0:
        empty = torch.zeros((0, 3), dtype=torch.long)
        return empty, empty
    t_values, t_flat = flat_q.topk(min(k, n_voxels))
    rot_bins, r_values = top_rotations(q_rot, k, separation)
    pairs = [(t_values[0] + r_values[j], 0, j) for j in range(len(r_values))]
    pairs += [(t_values[i] + r_values[0], i, 0) for i in range(1, len(t_values))]
    pairs = sorted(pairs, key=lambda p: -float(p[0]))[:k]
    voxels = unflatten_index(t_flat[torch.tensor([p[1] for p in pairs], dtype=torch.long)], q_trans.shape[0])
    rotations = rot_bins[torch.tensor([p[2] for p in pairs], dtype=torch.long)]
    if fallback_rotation is not None:
        fallback = fallback_rotation.to(rotations).reshape(1, 3)
        best = voxels[:1]
        known = ((voxels == best).all(1) & (rotations == fallback).all(1)).any()
        if not known:
            keep = min(len(pairs), k - 1)
            voxels = torch.cat([voxels[:keep], best])
            rotations = torch.cat([rotations[:keep], fallback])
    return voxels, rotations
