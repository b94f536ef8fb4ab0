"""Resource limits every receiver enforces while decoding, so no message can exhaust it.

The defaults fit every configuration in ``configs/``; a receiver with other needs passes its
own: ``decode(data, limits=Limits(max_batch=cfg.max_batch))`` or
``dataclasses.replace(DEFAULT_LIMITS, max_steps=...)``. ``encode`` checks against the same
limits, so a sender learns at once that its message would be refused.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Largest integer a JSON field may carry: every id, version, seed and counter stays exact
#: for any JSON reader (IEEE doubles are exact up to 2**53).
MAX_INT = 2**53 - 1


@dataclass(frozen=True)
class Limits:
    """Ceilings checked by :func:`protocol.messages.decode` (and ``encode``)."""

    max_bytes: int = 256 * 1024 * 1024  #: one message (a 4-camera, 10-step 128 px episode is ~12 MB)
    max_header_bytes: int = 1024 * 1024  #: the safetensors JSON header (fields plus array table)
    max_json_depth: int = 32  #: nesting of any JSON in a frame (the schemas need 4)
    max_arrays: int = 4096  #: arrays in one message (weights of every depth, batch columns)
    max_ndim: int = 8  #: dimensions of one array
    max_dim: int = 2**31 - 1  #: length of one array dimension
    max_steps: int = 1000  #: steps (decisions) per episode
    max_cameras: int = 8  #: cameras per episode
    max_image_side: int = 1024  #: image height and width, pixels
    max_extras: int = 32  #: ``extra_*`` observation arrays per episode
    max_depths: int = 8  #: cascade depths in act-time labels
    max_batch: int = 1024  #: ``SampleRequest.batch_size`` (B=1024 at 4x128 px is ~1.2 GB)
    max_priorities: int = 65536  #: entries of one ``PriorityUpdate``
    max_timeout_ms: int = 600_000  #: ``SampleRequest.timeout_ms``
    max_items: int = 1024  #: entries of a counters/info/... map
    max_text: int = 4096  #: characters of a free-text field (reasons, errors, info values)
    max_name: int = 256  #: characters of an array name or a map key


DEFAULT_LIMITS = Limits()
