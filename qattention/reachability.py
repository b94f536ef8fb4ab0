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
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from .voxelise import unflatten_index

#: ``reachable(action [8]) -> bool``: can the arm take this next-best pose (xyz, quat xyzw, gripper)?
ReachabilityTest = Callable[[np.ndarray], bool]


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
    i, j, l = np.unravel_index(best.indices.cpu().numpy(), n)
    return torch.stack([per_axis[0][i], per_axis[1][j], per_axis[2][l]], 1), best.values


def ranked_candidates(q_trans: torch.Tensor, q_rot: torch.Tensor, k: int,
                      separation: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """Up to ``k`` (voxel, rotation) candidates of one sample, best joint Q first.

    ``q_trans`` [V, V, V] is the last depth's translation Q, ``q_rot`` [3, bins] its rotation Q.
    A pose is out of reach either for its orientation or for its position (e.g. a voxel of the
    child cube outside the workspace), so the candidates are the best rotations (bins at least
    ``separation`` apart per axis) at the best voxel, and the best voxels with the best rotation.
    Returns voxel indices [n, 3] and Euler bins [n, 3], n <= k.
    """
    t_values, t_flat = q_trans.reshape(-1).topk(min(k, q_trans.numel()))
    rot_bins, r_values = top_rotations(q_rot, k, separation)
    pairs = [(t_values[0] + r_values[j], 0, j) for j in range(len(r_values))]
    pairs += [(t_values[i] + r_values[0], i, 0) for i in range(1, len(t_values))]
    pairs = sorted(pairs, key=lambda p: -float(p[0]))[:k]
    ti = torch.tensor([p[1] for p in pairs], dtype=torch.long)
    ri = torch.tensor([p[2] for p in pairs], dtype=torch.long)
    return unflatten_index(t_flat[ti], q_trans.shape[0]), rot_bins[ri]
