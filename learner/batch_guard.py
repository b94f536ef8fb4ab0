"""The learner's check on a sampled batch before it reaches the loss: hostile until validated.

A NaN or inf in any array that feeds the update (rewards, poses, camera matrices, importance
weights, labels, ...) would make the loss and then every weight NaN. Point clouds are the
exception: invalid depth is normal for a real camera, and voxelisation drops non-finite
points, so ``*_points`` arrays may hold them. Integer and bool arrays are always finite.

Act-time labels are indices into this learner's own Q maps. The wire only knows they are
non-negative (it does not know the network), so the learner checks them against its voxel
grid, depth count and rotation bins: an index past the end would make the gather in the
loss raise (on CPU) or abort the device (on CUDA) instead of skipping one row.
"""

from __future__ import annotations

import numpy as np

from protocol import transition as tr

#: Arrays in which non-finite values are meaningful (invalid depth) and handled downstream.
POINT_SUFFIXES = ("_points", tr.next_name("_points"))


def nonfinite_rows(arrays: dict[str, np.ndarray]) -> tuple[list[str], np.ndarray]:
    """(names of poisoned arrays, bool [B] rows that hold a non-finite value outside point clouds)."""
    b = len(arrays[tr.INDICES])
    rows = np.zeros(b, bool)
    names = []
    for name, a in arrays.items():
        if name.endswith(POINT_SUFFIXES) or a.dtype.kind not in "fc":
            continue
        finite = np.isfinite(a)
        if finite.all():
            continue
        names.append(name)
        if a.ndim and a.shape[0] == b:
            rows |= ~finite.reshape(b, -1).all(1)
        else:  # not per-row: every row is suspect
            rows[:] = True
    return names, rows


def label_out_of_range_rows(arrays: dict[str, np.ndarray], voxel_size: int, depths: int,
                            rotation_bins: int) -> tuple[list[str], np.ndarray]:
    """(names of bad label arrays, bool [B] rows whose act-time labels do not fit the network).

    ``voxel_indices`` [B, D, 3] must have D == ``depths`` and entries < ``voxel_size``;
    ``rot_grip_indices`` [B, 4] three Euler bins < ``rotation_bins`` and a gripper bin < 2;
    ``attention_coordinates`` [B, D, 3] the same D. Missing labels are fine (recomputed).
    """
    b = len(arrays[tr.INDICES])
    rows = np.zeros(b, bool)
    names = []
    limits = {
        "voxel_indices": (3, np.full(3, voxel_size)),
        "attention_coordinates": (3, None),
        "rot_grip_indices": (4, np.array([rotation_bins] * 3 + [2])),
    }
    for label, (width, upper) in limits.items():
        name = tr.extra_name(label)
        a = arrays.get(name)
        if a is None:
            continue
        per_depth = label != "rot_grip_indices"
        shape_ok = a.shape == ((b, depths, width) if per_depth else (b, width))
        if not shape_ok:
            names.append(name)
            rows[:] = True
            continue
        if upper is None:
            continue
        bad = ((a < 0) | (a >= upper)).reshape(b, -1).any(1)
        if bad.any():
            names.append(name)
            rows |= bad
    return names, rows


def nstep_out_of_range_rows(arrays: dict[str, np.ndarray]) -> tuple[list[str], np.ndarray]:
    """(names of bad n-step arrays, bool [B] rows whose n-step fields do not describe a transition).

    ``n_rewards`` [B, n] and ``bootstrap_steps`` [B] come together or not at all, and each
    ``bootstrap_steps`` lies in 1..n: a zero would bootstrap from the observation itself, a
    larger one discount by more steps than the rewards cover.
    """
    b = len(arrays[tr.INDICES])
    rewards, steps = arrays.get(tr.N_REWARDS), arrays.get(tr.BOOTSTRAP_STEPS)
    if rewards is None and steps is None:
        return [], np.zeros(b, bool)
    if rewards is None or steps is None or rewards.ndim != 2 or rewards.shape[0] != b or steps.shape != (b,):
        return [tr.N_REWARDS, tr.BOOTSTRAP_STEPS], np.ones(b, bool)
    bad = (steps < 1) | (steps > rewards.shape[1])
    return ([tr.BOOTSTRAP_STEPS] if bad.any() else []), bad
