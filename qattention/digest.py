"""A short fingerprint of everything that shapes the networks' weights.

The learner stamps it on every weights broadcast; an actor built with a different network
config refuses those weights instead of failing on a shape mismatch mid-episode.
"""

from __future__ import annotations

import hashlib
import json

from qattention.config import QAttentionConfig

#: Fields that change parameter names or shapes.
NETWORK_FIELDS = ("voxel_size", "depths", "rotation_resolution", "kernels", "head_width")


def network_digest(config: QAttentionConfig) -> str:
    shape = {name: getattr(config, name) for name in NETWORK_FIELDS}
    return hashlib.sha256(json.dumps(shape, sort_keys=True).encode()).hexdigest()[:16]
