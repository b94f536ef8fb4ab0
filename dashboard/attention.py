"""``/api/qattention``: the latest Q-attention snapshot (``runs/<id>/eval/qattention-latest.npz``) as JSON.

The evaluator writes the file atomically after every evaluation (protocol/attention_snapshot.py is the format);
here it is only read (``allow_pickle=False``) and memoised on its stamp. Coordinates are
rounded to 0.1 mm and voxel lists are flat ``[x0, y0, z0, x1, ...]`` arrays, so a 16^3 grid
with a thousand occupied voxels stays a few tens of kB.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dashboard.filecache import FileCache
from protocol.attention_snapshot import FILENAME, Snapshot, load_snapshot


class AttentionSnapshot:
    def __init__(self, run_dir: Path, cache: FileCache | None = None) -> None:
        self.path = Path(run_dir) / "eval" / FILENAME
        self.cache = cache or FileCache()

    def latest(self) -> tuple[dict, str]:
        """(the /api/qattention body, its ETag); ``available`` false while no evaluation has finished."""
        return self.cache.for_files("qattention", [self.path], self._build)

    def _build(self) -> dict:
        if not self.path.is_file():
            return {"available": False, "reason": "no evaluation has finished yet"}
        try:
            snapshot = load_snapshot(self.path)
        except (OSError, ValueError, KeyError) as e:
            return {"available": False, "reason": f"unreadable snapshot: {e}"}
        return snapshot_json(snapshot)


def snapshot_json(s: Snapshot) -> dict:
    depths = []
    for d, view in enumerate(s.depths):
        bounds = view.bounds.astype(np.float64)
        depths.append({
            "depth": d,
            "bounds": _flat(bounds),
            "voxel_edge": _flat((bounds[3:] - bounds[:3]) / s.voxel_size),
            "occupied": {"count": int(len(view.occupied_index)), "centres": _flat(view.occupied_centres),
                         "rgb": [int(c) for c in view.occupied_rgb.reshape(-1)]},
            "top": {"index": view.top_index.astype(int).tolist(), "centres": _flat(view.top_centres),
                    "q": [round(float(q), 5) for q in view.top_q]},
            "chosen": {"index": view.chosen_index.astype(int).tolist(), "centre": _flat(view.chosen_centre),
                       "q": round(float(view.chosen_q), 5)},
        })
    return {"available": True, "meta": s.meta, "voxel_size": s.voxel_size,
            "action": [round(float(a), 4) for a in s.action], "depths": depths}


def _flat(a: np.ndarray) -> list[float]:
    return [round(float(x), 4) for x in np.asarray(a).reshape(-1)]
