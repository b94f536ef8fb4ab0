"""The Q-attention snapshot file: what Q-attention attended to at one decision, for the dashboard.

The evaluator writes one after every evaluation (``actors/qattention_snapshot.py`` computes it);
the dashboard reads it (``dashboard/attention.py``). This module is the format both sides share.

Files are plain ``np.savez`` arrays (no pickle; load with ``allow_pickle=False``) written to
a temp file and moved into place with ``os.replace``, so a reader never sees half a file.
Keys: ``format``, ``voxel_size``, ``depths``, ``action`` [8], ``meta`` (a JSON string) and,
per depth ``d``, ``d{d}_bounds`` [6], ``d{d}_occupied_index`` [N, 3], ``d{d}_occupied_centres``
[N, 3], ``d{d}_occupied_rgb`` uint8 [N, 3], ``d{d}_top_index`` [K, 3], ``d{d}_top_centres``
[K, 3], ``d{d}_top_q`` [K], ``d{d}_chosen_index`` [3], ``d{d}_chosen_centre`` [3],
``d{d}_chosen_q`` [].
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FORMAT = "c2farm-qattention/1"
TOP_K = 20  #: voxels highlighted per depth
FILENAME = "qattention-latest.npz"  #: under runs/<id>/eval/

_ARRAYS = ("bounds", "occupied_index", "occupied_centres", "occupied_rgb", "top_index", "top_centres", "top_q",
           "chosen_index", "chosen_centre", "chosen_q")


@dataclass
class DepthView:
    """One depth of the cascade at one decision."""

    bounds: np.ndarray  #: float32 [6] the box this depth voxelised (min xyz, max xyz), metres
    occupied_index: np.ndarray  #: int16 [N, 3] voxels that hold at least one point
    occupied_centres: np.ndarray  #: float32 [N, 3] their centres, world frame
    occupied_rgb: np.ndarray  #: uint8 [N, 3] their mean colour
    top_index: np.ndarray  #: int16 [K, 3] the K voxels of highest translation Q, best first
    top_centres: np.ndarray  #: float32 [K, 3]
    top_q: np.ndarray  #: float32 [K]
    chosen_index: np.ndarray  #: int16 [3] the voxel the agent chose (what it executed)
    chosen_centre: np.ndarray  #: float32 [3]
    chosen_q: np.ndarray  #: float32 [] its Q


@dataclass
class Snapshot:
    depths: list[DepthView]
    action: np.ndarray  #: float32 [8] executed next-best pose: xyz, quat xyzw, gripper open
    voxel_size: int
    meta: dict = field(default_factory=dict)  #: weights_version, task, seed, time, ...


def save_snapshot(path: str | Path, snapshot: Snapshot) -> None:
    """Write ``snapshot`` atomically (temp file in the same folder, then ``os.replace``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {"format": np.asarray(FORMAT), "voxel_size": np.asarray(snapshot.voxel_size),
              "depths": np.asarray(len(snapshot.depths)), "action": snapshot.action,
              "meta": np.asarray(json.dumps(snapshot.meta))}
    for d, view in enumerate(snapshot.depths):
        for name in _ARRAYS:
            arrays[f"d{d}_{name}"] = np.asarray(getattr(view, name))
    fd, tmp = tempfile.mkstemp(prefix=".qattention-", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def load_snapshot(path: str | Path) -> Snapshot:
    """Read a snapshot file (plain arrays only: ``allow_pickle=False``); ValueError if it is not one."""
    with np.load(Path(path), allow_pickle=False) as z:
        if "format" not in z.files or str(z["format"]) != FORMAT:
            raise ValueError(f"{path}: not a {FORMAT} file")
        depths = [DepthView(**{name: z[f"d{d}_{name}"] for name in _ARRAYS}) for d in range(int(z["depths"]))]
        return Snapshot(depths=depths, action=z["action"], voxel_size=int(z["voxel_size"]),
                        meta=json.loads(str(z["meta"])))
