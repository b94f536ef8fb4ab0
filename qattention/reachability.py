"""Reachability-aware acting: the best-Q next-best pose among the top-K that the arm can reach.

The cascade picks every head's argmax on its own, so nothing stops it from asking for a
gripper orientation the arm cannot take at that point; the reference then ends the episode
on an unreachable pose (reward 0), and early in training most exploring episodes end that
way (89 % on pick_and_lift, BENCHMARKS.md). Given a cheap reachability test from the control
agent (IK only, no planning), the cascade can instead keep its choice when it is reachable
and otherwise take the best joint candidate of the last depth that is. Candidates are ranked
by ``Q_trans(voxel) + mean over axes of Q_rot(bin)``: every head regresses the same TD
target, so their values share one scale. K <= 1 (off) reproduces the reference.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from .voxelise import unflatten_index

#: ``reachable(action [8]) -> bool``: can the arm take this next-best pose (xyz, quat xyzw, gripper)?
ReachabilityTest = Callable[[np.ndarray], bool]


def top_rotations(q_rot: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` best Euler-bin triplets of ``q_rot`` [3, bins]: bins [k, 3] and their mean Q [k]."""
    m = min(k, q_rot.shape[1])
    values, bins = q_rot.topk(m, dim=1)  # [3, m]: only each axis's best m bins can make a top-k triplet
    score = (values[0][:, None, None] + values[1][None, :, None] + values[2][None, None, :]) / 3
    best = score.reshape(-1).topk(min(k, score.numel()))
    i, j, l = np.unravel_index(best.indices.cpu().numpy(), (m, m, m))
    return torch.stack([bins[0, i], bins[1, j], bins[2, l]], 1), best.values


def ranked_candidates(q_trans: torch.Tensor, q_rot: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` best (voxel, rotation) pairs of one sample, best first.

    ``q_trans`` [V, V, V] is the last depth's translation Q, ``q_rot`` [3, bins] its rotation Q.
    Returns voxel indices [k, 3] and Euler bins [k, 3].
    """
    t_values, t_flat = q_trans.reshape(-1).topk(min(k, q_trans.numel()))
    rot_bins, r_values = top_rotations(q_rot, k)
    score = t_values[:, None] + r_values[None, :]  # [k_t, k_r]
    best = score.reshape(-1).topk(min(k, score.numel())).indices
    ti, ri = best // score.shape[1], best % score.shape[1]
    return unflatten_index(t_flat[ti], q_trans.shape[0]), rot_bins[ri]
