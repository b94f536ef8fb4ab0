"""Bytes on the wire: an 8-byte frame header followed by a safetensors body. No pickle.

Frame layout::

    b"C2FA" | u16 protocol version | u16 message kind | safetensors(arrays, {"fields": json})

The safetensors format (a length-prefixed JSON header, then raw little-endian buffers) is
safe to parse from untrusted bytes and readable from any language, which is what lets a
real robot written in C++ or Rust join as one more actor. Scalar fields travel as JSON in
the safetensors metadata; arrays travel as raw buffers.

Every input is hostile: :func:`decode_frame` and :func:`peek_fields` raise
:class:`ProtocolError` and nothing else, whatever the bytes. Before any JSON is parsed its
size and nesting depth are checked without recursion, and the array table is checked
(dtype, shape, byte ranges) before a buffer is touched.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import struct
from typing import Any

import numpy as np
from safetensors.numpy import load as _load_arrays
from safetensors.numpy import save as _save_arrays

from protocol.limits import DEFAULT_LIMITS, MAX_INT, Limits

MAGIC = b"C2FA"
PROTOCOL_VERSION = 1
_FRAME = struct.Struct("<4sHH")

#: Default ceiling for one message (a 4-camera, 10-step episode is ~12 MB).
DEFAULT_MAX_BYTES = DEFAULT_LIMITS.max_bytes

#: The only array dtypes on the wire, by their safetensors names (little-endian).
SAFETENSORS_DTYPES: dict[str, np.dtype] = {
    "U8": np.dtype("uint8"),
    "BOOL": np.dtype("bool"),
    "I32": np.dtype("int32"),
    "I64": np.dtype("int64"),
    "F16": np.dtype("float16"),
    "F32": np.dtype("float32"),
    "F64": np.dtype("float64"),
}
#: Array dtypes allowed on the wire.
WIRE_DTYPES = frozenset(SAFETENSORS_DTYPES.values())

#: Array names and map keys that go into logs and dicts: printable, no spaces.
_NAME = re.compile(r"[A-Za-z0-9_.:/\-]+")
#: A JSON string literal (unrolled loop: linear time, no backtracking blow-up).
_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.S)
_OPEN = np.zeros(256, np.int32)
_OPEN[[ord("["), ord("{")]] = 1
_OPEN[[ord("]"), ord("}")]] = -1


class ProtocolError(ValueError):
    """A message that cannot be accepted. ``field`` names the part at fault."""

    def __init__(self, field: str, reason: str):
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


def encode_frame(kind: int, fields: dict[str, Any], arrays: dict[str, np.ndarray]) -> bytes:
    """Serialise one message: JSON-able ``fields`` plus named ``arrays`` (no schema check)."""
    for name, array in arrays.items():
        if not isinstance(array, np.ndarray) or array.dtype not in WIRE_DTYPES:
            raise ProtocolError(name, f"dtype {getattr(array, 'dtype', type(array).__name__)} cannot go on the wire")
    body = _save_arrays(
        {name: np.ascontiguousarray(a) for name, a in arrays.items()},
        metadata={"fields": json.dumps(fields, separators=(",", ":"))},
    )
    return _FRAME.pack(MAGIC, PROTOCOL_VERSION, kind) + body


def decode_frame(
    data: bytes, max_bytes: int | None = None, limits: Limits = DEFAULT_LIMITS
) -> tuple[int, dict[str, Any], dict[str, np.ndarray]]:
    """Parse one frame into ``(kind, fields, arrays)`` or raise :class:`ProtocolError`.

    ``max_bytes`` (default ``limits.max_bytes``) bounds the whole message.
    """
    max_bytes = limits.max_bytes if max_bytes is None else max_bytes
    view = _as_bytes(data)
    if len(view) > max_bytes:
        raise ProtocolError("frame", f"{len(view)} bytes exceeds the limit of {max_bytes}")
    kind, version = _frame_header(view)
    if version != PROTOCOL_VERSION:
        raise ProtocolError(
            "frame.version", f"protocol version {version}, this process speaks {PROTOCOL_VERSION}"
        )
    body = view[_FRAME.size :]
    header, data_start = _read_header(body, limits)
    fields = _fields_of(header, limits)
    table = _array_table(header, len(body) - data_start, limits)
    if not table:
        return kind, fields, {}
    try:
        arrays = _load_arrays(bytes(body))
    except Exception as exc:  # the table was checked; this is a last resort, never a crash
        raise ProtocolError("frame.body", f"malformed safetensors body ({type(exc).__name__}: {exc})") from None
    if arrays.keys() != table.keys():
        raise ProtocolError("frame.body", "array table and buffers disagree")
    for name, (dtype, shape) in table.items():
        if arrays[name].dtype != dtype or arrays[name].shape != shape:
            raise ProtocolError(name, "array table and buffers disagree")
    return kind, fields, arrays


def peek_fields(data: bytes, limits: Limits = DEFAULT_LIMITS) -> dict[str, Any]:
    """The scalar fields of a frame without checking its version or parsing its arrays.

    For naming the sender of a message that is being rejected (so it can be told why); the
    fields are *not* validated against any schema. Raises :class:`ProtocolError` when even
    the fields cannot be read.
    """
    view = _as_bytes(data)
    if len(view) > limits.max_bytes:
        raise ProtocolError("frame", f"{len(view)} bytes exceeds the limit of {limits.max_bytes}")
    _frame_header(view)
    header, _ = _read_header(view[_FRAME.size :], limits)
    return _fields_of(header, limits)


# -- frame and header ---------------------------------------------------------------------


def _as_bytes(data) -> memoryview:
    try:
        view = memoryview(data)
        if view.ndim != 1 or view.itemsize != 1:
            view = view.cast("B")
        return view
    except (TypeError, ValueError):
        raise ProtocolError("frame", f"expected bytes, got {type(data).__name__}") from None


def _frame_header(view: memoryview) -> tuple[int, int]:
    if len(view) < _FRAME.size + 8:
        raise ProtocolError("frame", f"truncated: {len(view)} bytes is shorter than any message")
    magic, version, kind = _FRAME.unpack_from(view)
    if magic != MAGIC:
        raise ProtocolError("frame.magic", f"expected {MAGIC!r}, got {bytes(magic)!r}")
    return kind, version


def _read_header(body: memoryview, limits: Limits) -> tuple[dict[str, Any], int]:
    """The safetensors JSON header (size and depth checked first) and where the data starts."""
    (header_len,) = struct.unpack_from("<Q", body)
    if header_len > limits.max_header_bytes:
        raise ProtocolError("frame.header", f"{header_len} bytes exceeds the limit of {limits.max_header_bytes}")
    if header_len > len(body) - 8:
        raise ProtocolError("frame.body", "truncated: header runs past the end of the message")
    header = parse_json(bytes(body[8 : 8 + header_len]), "frame.header", limits)
    if not isinstance(header, dict):
        raise ProtocolError("frame.header", "must be a JSON object")
    return header, 8 + header_len


def _fields_of(header: dict[str, Any], limits: Limits) -> dict[str, Any]:
    meta = header.get("__metadata__")
    if not isinstance(meta, dict) or set(meta) != {"fields"} or not isinstance(meta["fields"], str):
        raise ProtocolError("frame.fields", "missing or malformed field metadata")
    fields = parse_json(meta["fields"].encode("utf-8"), "frame.fields", limits)
    if not isinstance(fields, dict):
        raise ProtocolError("frame.fields", "fields must be a JSON object")
    return fields


def _array_table(header: dict[str, Any], data_len: int, limits: Limits) -> dict[str, tuple[np.dtype, tuple]]:
    """Check every array entry (dtype, shape, byte range) before any buffer is read."""
    entries = [(k, v) for k, v in header.items() if k != "__metadata__"]
    if len(entries) > limits.max_arrays:
        raise ProtocolError("frame.arrays", f"{len(entries)} arrays exceeds the limit of {limits.max_arrays}")
    table, ranges = {}, []
    for name, entry in entries:
        check_name(name, "frame.arrays", limits)
        if not isinstance(entry, dict) or set(entry) != {"dtype", "shape", "data_offsets"}:
            raise ProtocolError(name, "malformed array entry")
        dtype = SAFETENSORS_DTYPES.get(entry["dtype"]) if isinstance(entry["dtype"], str) else None
        if dtype is None:
            raise ProtocolError(name, f"dtype {entry['dtype']!r} is not a wire dtype {sorted(SAFETENSORS_DTYPES)}")
        shape, offsets = entry["shape"], entry["data_offsets"]
        if not isinstance(shape, list) or len(shape) > limits.max_ndim or not all(
            _is_int(d) and 0 <= d <= limits.max_dim for d in shape
        ):
            raise ProtocolError(name, f"bad shape {shape!r}")
        if not (isinstance(offsets, list) and len(offsets) == 2 and all(_is_int(o) for o in offsets)
                and 0 <= offsets[0] <= offsets[1] <= data_len):
            raise ProtocolError(name, f"bad data offsets {offsets!r}")
        if offsets[1] - offsets[0] != math.prod(shape) * dtype.itemsize:
            raise ProtocolError(name, f"{offsets[1] - offsets[0]} bytes do not hold {dtype.name}{shape}")
        table[name] = (dtype, tuple(shape))
        ranges.append(tuple(offsets))
    end = 0
    for begin, stop in sorted(ranges):
        if begin != end:
            raise ProtocolError("frame.arrays", "array buffers overlap or leave gaps")
        end = stop
    if end != data_len:
        raise ProtocolError("frame.arrays", f"{data_len - end} bytes after the last array")
    return table


# -- JSON ---------------------------------------------------------------------------------


class _Reject(ValueError):
    pass


def _no_duplicates(pairs):
    out = dict(pairs)
    if len(out) != len(pairs):
        raise _Reject("duplicate key")
    return out


def _bounded_int(text: str) -> int:
    if len(text.lstrip("-")) > 16:  # > 2**53 anyway; refuse before int() does any work
        raise _Reject(f"integer {text[:20]}... is too large")
    return int(text)


def json_depth(raw: bytes) -> int:
    """Deepest ``[``/``{`` nesting of a JSON text, found without recursion (strings skipped)."""
    counts = _OPEN[np.frombuffer(_JSON_STRING.sub(b'""', raw), np.uint8)]
    return int(np.cumsum(counts).max()) if counts.size else 0


def parse_json(raw: bytes, what: str, limits: Limits = DEFAULT_LIMITS) -> Any:
    """Parse untrusted JSON: depth checked before parsing, no duplicate keys, no huge integers,
    every string valid Unicode. ``NaN``/``Infinity`` parse; schemas decide where they may appear."""
    if json_depth(raw) > limits.max_json_depth:
        raise ProtocolError(what, f"JSON nested deeper than {limits.max_json_depth}")
    try:
        value = json.loads(raw.decode("utf-8"), object_pairs_hook=_no_duplicates, parse_int=_bounded_int)
        # A lone surrogate ("\ud800") would crash whoever prints or re-encodes it later.
        json.dumps(value, ensure_ascii=False).encode("utf-8")
    except _Reject as exc:
        raise ProtocolError(what, str(exc)) from None
    except UnicodeError:
        raise ProtocolError(what, "not valid UTF-8 / Unicode") from None
    except (ValueError, RecursionError, TypeError):
        raise ProtocolError(what, "malformed JSON") from None
    return value


# -- field helpers for the message schemas ---------------------------------------------------


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def check_keys(fields: dict[str, Any], expected: tuple[str, ...] | frozenset[str], what: str = "") -> None:
    """Reject a missing or unknown field, naming it."""
    for name in expected:
        if name not in fields:
            raise ProtocolError(what + name, "missing")
    for name in fields:
        if name not in expected:
            raise ProtocolError(what + str(name)[:64], "unknown field")


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


def check_int(name: str, value: Any, lo: int = 0, hi: int = MAX_INT) -> int:
    """An integer (not a bool, not a float) in ``lo..hi``."""
    if not _is_int(value):
        raise ProtocolError(name, f"expected int, got {type(value).__name__}")
    if not lo <= value <= hi:
        raise ProtocolError(name, f"{value} is outside {lo}..{hi}")
    return value


def check_float(name: str, value: Any, lo: float = -math.inf, hi: float = math.inf) -> float:
    """A finite number (int or float, not a bool) in ``lo..hi``, as a float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(name, f"expected a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value) or not lo <= value <= hi:
        raise ProtocolError(name, f"{value} is not a finite number in {lo}..{hi}")
    return value


def check_text(name: str, value: Any, max_len: int) -> str:
    """A string of at most ``max_len`` characters that encodes as UTF-8."""
    if not isinstance(value, str):
        raise ProtocolError(name, f"expected str, got {type(value).__name__}")
    if len(value) > max_len:
        raise ProtocolError(name, f"{len(value)} characters exceeds the limit of {max_len}")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise ProtocolError(name, "not valid Unicode") from None
    return value


def check_name(name: Any, what: str, limits: Limits = DEFAULT_LIMITS) -> str:
    """An array name: 1..``max_name`` of letters, digits and ``_ . : / -``."""
    if not isinstance(name, str) or not 1 <= len(name) <= limits.max_name or not _NAME.fullmatch(name):
        raise ProtocolError(what, f"bad name {str(name)[:64]!r}: use letters, digits, '_', '.', ':', '/', '-'")
    return name


def check_map(name: str, value: Any, limits: Limits, values: str) -> dict:
    """A JSON object of text keys to ``values`` ("text", "number" or "any-number").

    "any-number" admits NaN and infinities (diagnostics that report a diverged loss).
    """
    if not isinstance(value, dict):
        raise ProtocolError(name, f"expected an object, got {type(value).__name__}")
    if len(value) > limits.max_items:
        raise ProtocolError(name, f"{len(value)} entries exceeds the limit of {limits.max_items}")
    out = {}
    for key, item in value.items():
        check_text(f"{name}", key, limits.max_name)
        where = f"{name}.{key[:64]}"
        if values == "text":
            out[key] = check_text(where, item, limits.max_text)
        elif values == "number":
            out[key] = check_float(where, item)
        else:
            if isinstance(item, bool) or not isinstance(item, (int, float)):
                raise ProtocolError(where, f"expected a number, got {type(item).__name__}")
            out[key] = float(item)
    return out


def check_array_values(name: str, array: np.ndarray, finite: bool = True) -> None:
    """Values that cannot poison a consumer: bools stored as 0/1 (a stray byte 2 becomes
    2.0 in torch), floats finite unless ``finite`` is False (point clouds may hold NaN)."""
    if array.size == 0:
        return
    if array.dtype == np.bool_:
        if array.view(np.uint8).max() > 1:
            raise ProtocolError(name, "bool array holds bytes other than 0 and 1")
    elif finite and array.dtype.kind == "f" and not np.isfinite(array).all():
        raise ProtocolError(name, "holds NaN or infinite values")


def payload_digest(raw: bytes) -> str:
    """The digest of an encoded message: a resend is byte-identical, a forgery is not.

    The replay deduplicates episodes by it and returns it in every ack, so an actor only
    lets an ack retire the exact payload it sent. 64 bits: a forger needs a second preimage,
    not a birthday collision.
    """
    return hashlib.sha256(raw).hexdigest()[:16]


DIGEST_PATTERN = re.compile(r"[0-9a-f]{16}")
