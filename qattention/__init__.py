"""C2F-ARM's coarse-to-fine Q-attention in pure torch: voxel grid, networks, cascade, codec, TD update.

No processes or I/O here; actors call ``C2FARM.act``, the learner ``C2FARM.update``.
Deviations from the reference are listed in qattention/README.md.

The names below load on first use (PEP 562): every role reads ``qattention.config`` to
resolve its settings, and the replay server, router and dashboard should not pay torch's
import (seconds, hundreds of MB) for a dataclass.
"""

from importlib import import_module

#: public name -> submodule that defines it
_EXPORTS = {
    "ActionLabels": "action_codec", "decode_action": "action_codec", "encode_action": "action_codec",
    "C2FARM": "agent", "ObservationBatch": "batch", "TransitionBatch": "batch",
    "ActResult": "cascade", "descend": "cascade",
    "QAttentionConfig": "config", "cpu_small": "config", "paper": "config",
    "QAttentionNet": "q_attention", "build_networks": "q_attention",
    "child_bounds": "voxelise", "point_to_voxel_index": "voxelise", "voxel_centre": "voxelise",
}
# ``voxelise`` and ``proprioception`` are not re-exported: they are also submodule names, and
# once a submodule is imported its name on the package is the module. Import them from there.


def __getattr__(name: str):
    if name == "QAttentionAgent":
        name = "C2FARM"
    if name not in _EXPORTS:
        raise AttributeError(f"module 'qattention' has no attribute {name!r}")
    return getattr(import_module(f".{_EXPORTS[name]}", __name__), name)


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
    "voxel_centre",
]


def __dir__() -> list[str]:
    return sorted(__all__)
