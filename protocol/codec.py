"""Bytes on the wire: an 8-byte frame header followed by a safetensors body. No pickle.

Frame layout::

    b"C2FA" | u16 protocol version | u16 message kind | safetensors(arrays, {"fields": json})

The safetensors format (a length-prefixed JSON header, then raw little-endian buffers) is
safe to parse from untrusted bytes and readable from any language, which is what lets a
real robot written in C++ or Rust join as one more actor. Scalar fields travel as JSON in
the safetensors metadata; arrays travel as raw buffers.
"""

from __future__ import annotations

import json
import struct
from typing import Any

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load as _load_arrays
from safetensors.numpy import save as _save_arrays

MAGIC = b"C2FA"
PROTOCOL_VERSION = 1
_FRAME = struct.Struct("<4sHH")

#: Default ceiling for one message (a 4-camera, 10-step episode is ~12 MB).
DEFAULT_MAX_BYTES = 256 * 1024 * 1024

#: Array dtypes allowed on the wire.
WIRE_DTYPES = frozenset(
    np.dtype(d) for d in ("uint8", "bool", "int32", "int64", "float16", "float32", "float64")
)


class ProtocolError(ValueError):
    """A message that cannot be accepted. ``field`` names the part at fault."""

    def __init__(self, field: str, reason: str):
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


def encode_frame(kind: int, fields: dict[str, Any], arrays: dict[str, np.ndarray]) -> bytes:
    """Serialise one message: JSON-able ``fields`` plus named ``arrays``."""
    for name, array in arrays.items():
        if array.dtype not in WIRE_DTYPES:
            raise ProtocolError(name, f"dtype {array.dtype} cannot go on the wire")
    body = _save_arrays(
        {name: np.ascontiguousarray(a) for name, a in arrays.items()},
        metadata={"fields": json.dumps(fields, separators=(",", ":"))},
    )
    return _FRAME.pack(MAGIC, PROTOCOL_VERSION, kind) + body


def decode_frame(
    data: bytes, max_bytes: int = DEFAULT_MAX_BYTES
) -> tuple[int, dict[str, Any], dict[str, np.ndarray]]:
    """Parse one frame into ``(kind, fields, arrays)`` or raise :class:`ProtocolError`."""
    if len(data) > max_bytes:
        raise ProtocolError("frame", f"{len(data)} bytes exceeds the limit of {max_bytes}")
    if len(data) < _FRAME.size + 8:
        raise ProtocolError("frame", f"truncated: {len(data)} bytes is shorter than any message")
    magic, version, kind = _FRAME.unpack_from(data)
    if magic != MAGIC:
        raise ProtocolError("frame.magic", f"expected {MAGIC!r}, got {bytes(magic)!r}")
    if version != PROTOCOL_VERSION:
        raise ProtocolError(
            "frame.version", f"protocol version {version}, this process speaks {PROTOCOL_VERSION}"
        )
    body = memoryview(data)[_FRAME.size :]
    fields = _read_fields(body)
    try:
        arrays = _load_arrays(bytes(body))
    except SafetensorError as exc:
        raise ProtocolError("frame.body", f"malformed safetensors body ({exc})") from None
    return kind, fields, arrays


def peek_fields(data: bytes) -> dict[str, Any]:
    """The scalar fields of a frame without checking its version or parsing its arrays.

    For naming the sender of a message that is being rejected (so it can be told why);
    raises :class:`ProtocolError` when even the fields cannot be read.
    """
    if len(data) < _FRAME.size + 8 or bytes(data[:4]) != MAGIC:
        raise ProtocolError("frame", "not a c2farm frame")
    return _read_fields(memoryview(data)[_FRAME.size :])


def _read_fields(body: memoryview) -> dict[str, Any]:
    """Read the JSON scalar fields from the safetensors header without touching the buffers."""
    (header_len,) = struct.unpack_from("<Q", body)
    if header_len > len(body) - 8:
        raise ProtocolError("frame.body", "truncated: header runs past the end of the message")
    try:
        header = json.loads(bytes(body[8 : 8 + header_len]))
        fields = json.loads(header["__metadata__"]["fields"])
    except (ValueError, KeyError, TypeError):
        raise ProtocolError("frame.fields", "missing or malformed field metadata") from None
    if not isinstance(fields, dict):
        raise ProtocolError("frame.fields", "fields must be a JSON object")
    return fields


def require(fields: dict[str, Any], name: str, kind: type | tuple[type, ...]) -> Any:
    """Fetch ``fields[name]`` and check its JSON type (bool is never accepted as int)."""
    if name not in fields:
        raise ProtocolError(name, "missing")
    value = fields[name]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool) and bool not in kinds:
        raise ProtocolError(name, f"expected {kinds[0].__name__}, got bool")
    if not isinstance(value, kinds):
        raise ProtocolError(name, f"expected {kinds[0].__name__}, got {type(value).__name__}")
    return value
