"""C2F-ARM's coarse-to-fine Q-attention in pure torch: voxel grid, networks, cascade, codec, TD update.

No processes or I/O here; actors call ``C2FARM.act``, the learner ``C2FARM.update``.
Deviations from the reference are listed in README.md.
"""

from .action_codec import ActionLabels, decode_action, encode_action
from .agent import C2FARM
from .batch import ObservationBatch, TransitionBatch
from .cascade import ActResult, descend
from .config import QAttentionConfig, cpu_small, paper
from .proprioception import proprioception
from .q_attention import QAttentionNet, build_networks
from .voxelise import child_bounds, point_to_voxel_index, voxel_centre, voxelise

QAttentionAgent = C2FARM

__all__ = [
    "ActResult",
    "ActionLabels",
    "C2FARM",
    "ObservationBatch",
    "QAttentionAgent",
    "QAttentionConfig",
    "QAttentionNet",
    "TransitionBatch",
    "build_networks",
    "child_bounds",
    "cpu_small",
    "decode_action",
    "descend",
    "encode_action",
    "paper",
    "point_to_voxel_index",
    "proprioception",
    "voxel_centre",
    "voxelise",
]
