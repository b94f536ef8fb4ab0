"""The learner's check on a sampled batch before it reaches the loss: hostile until validated.

A NaN or inf in any array that feeds the update (rewards, poses, camera matrices, importance
weights, labels, ...) would make the loss and then every weight NaN. Point clouds are the
exception: invalid depth is normal for a real camera, and voxelisation drops non-finite
points, so ``*_points`` arrays may hold them. Integer and bool arrays are always finite.
"""

from __future__ import annotations

import numpy as np

#: Arrays in which non-finite values are meaningful (invalid depth) and handled downstream.
POINT_SUFFIXES = ("_points", "_points_tp1")


def nonfinite_rows(arrays: dict[str, np.ndarray]) -> tuple[list[str], np.ndarray]:
    """(names of poisoned arrays, bool [B] rows that hold a non-finite value outside point clouds)."""
    b = len(arrays["indices"])
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
