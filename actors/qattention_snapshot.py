"""What Q-attention attended to at one decision, computed for the dashboard (the paper's Figure 2, live).

For one observation and per depth: the voxel grid the network saw (occupied voxels' centres
and mean colours, the grid's bounds), the top-K voxels by translation Q with their values,
and the chosen voxel; plus the executed gripper pose. It is recomputed with the public
qattention steps that ``qattention.cascade.descend`` runs (gather points, voxelise, one
network per depth), so acting itself is untouched; it costs one forward pass per depth,
once per evaluation. The file format is ``protocol.attention_snapshot``'s.
"""

from __future__ import annotations

import contextlib

import numpy as np

from protocol.attention_snapshot import TOP_K, DepthView, Snapshot


def compute_snapshot(agent, observation, action: np.ndarray | None = None, top_k: int = TOP_K,
                     meta: dict | None = None) -> Snapshot:
    """The snapshot of ``agent`` (a ``qattention.C2FARM``) deciding on ``observation``.

    The chosen voxels come from the act-time labels the actor stored in
    ``observation.extras`` (so a reachability replacement shows as executed), else from a
    fresh greedy ``agent.act``; ``action`` is the executed pose (else the act's).
    """
    import torch

    from qattention.batch import ObservationBatch
    from qattention.cascade import depth_grid
    from qattention.voxelise import child_bounds, unflatten_index, voxel_centre

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
    proprio = batch.proprioception(cfg)
    v = cfg.voxel_size
    bounds, centre = batch.bounds(cfg.scene_bounds), None
    autocast = (torch.autocast(device.type, dtype=torch.bfloat16) if agent.bf16 else contextlib.nullcontext())
    depths = []
    agent.nets.eval()
    with torch.no_grad():
        for d in range(cfg.depths):
            grid = depth_grid(batch, cfg, centre, bounds)  # [1, 10, V, V, V]: mean xyz, mean rgb, index, occupancy
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
