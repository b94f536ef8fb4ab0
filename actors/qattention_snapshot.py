"""What Q-attention attended to at one decision, saved for the dashboard (the paper's Figure 2, live).

For one observation and per depth: the voxel grid the network saw (occupied voxels' centres
and mean colours, the grid's bounds), the top-K voxels by translation Q with their values,
and the chosen voxel; plus the executed gripper pose. It is recomputed with the public
qattention steps that ``qattention.cascade.descend`` runs (gather points, voxelise, one
network per depth), so acting itself is untouched; it costs one forward pass per depth,
once per evaluation.

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


def compute_snapshot(agent, observation, action: np.ndarray | None = None, top_k: int = TOP_K,
                     meta: dict | None = None) -> Snapshot:
    """The snapshot of ``agent`` (a ``qattention.C2FARM``) deciding on ``observation``.

    The chosen voxels come from the act-time labels the actor stored in
    ``observation.extras`` (so a reachability replacement shows as executed), else from a
    fresh greedy ``agent.act``; ``action`` is the executed pose (else the act's).
    """
    import torch

    from qattention.batch import ObservationBatch
    from qattention.crop import gather_points
    from qattention.voxelise import child_bounds, unflatten_index, voxel_centre, voxelise

    cfg, device = agent.config, agent.device
    batch = ObservationBatch.from_observations([observation], cfg.cameras, device)
    chosen = observation.extras.get("voxel_indices")
    centres = observation.extras.get("attention_coordinates")
    if chosen is None or centres is None or action is None:
        act = agent.act(batch)
        chosen, centres = act.voxel_indices[0], act.attention_coordinates[0]
        action = act.action[0] if action is None else action
    chosen = torch.as_tensor(np.asarray(chosen), dtype=torch.long, device=device).reshape(cfg.depths, 3)
    centres = torch.as_tensor(np.asarray(centres), dtype=torch.float32, device=device).reshape(cfg.depths, 3)
    proprio = batch.proprioception(cfg.episode_length)
    v = cfg.voxel_size
    bounds, centre = batch.bounds(cfg.scene_bounds), None
    autocast = (torch.autocast(device.type, dtype=torch.bfloat16) if agent.bf16 else contextlib.nullcontext())
    depths = []
    agent.nets.eval()
    with torch.no_grad():
        for d in range(cfg.depths):
            points, rgb = gather_points(batch, cfg.cameras, centre, cfg.image_crop)
            grid = voxelise(points, rgb, bounds, v)  # [1, 10, V, V, V]: mean xyz, mean rgb, index, occupancy
            with autocast:
                q_trans, _ = agent.nets[d](grid, proprio)
            q = q_trans[0].float()
            occupied = torch.nonzero(grid[0, 9] > 0)
            colours = grid[0, 3:6, occupied[:, 0], occupied[:, 1], occupied[:, 2]].T
            k = min(top_k, q.numel())
            top_q, top_flat = q.reshape(-1).topk(k)
            top = unflatten_index(top_flat, v)
            c = chosen[d]
            depths.append(DepthView(
                bounds=_np(bounds[0], np.float32),
                occupied_index=_np(occupied, np.int16),
                occupied_centres=_np(voxel_centre(occupied, bounds[0], v), np.float32),
                occupied_rgb=np.clip(np.rint((_np(colours, np.float32) + 1.0) * 127.5), 0, 255).astype(np.uint8),
                top_index=_np(top, np.int16),
                top_centres=_np(voxel_centre(top, bounds[0], v), np.float32),
                top_q=_np(top_q, np.float32),
                chosen_index=_np(c, np.int16),
                chosen_centre=_np(voxel_centre(c, bounds[0], v), np.float32),
                chosen_q=np.asarray(float(q[c[0], c[1], c[2]]), np.float32),
            ))
            if d < cfg.depths - 1:
                centre = centres[d][None]
                bounds = child_bounds(centre, cfg.offset(d + 1))
    return Snapshot(depths=depths, action=np.asarray(action, np.float32).reshape(8), voxel_size=v,
                    meta=dict(meta or {}))


def _np(t, dtype) -> np.ndarray:
    return t.detach().cpu().numpy().astype(dtype)


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
