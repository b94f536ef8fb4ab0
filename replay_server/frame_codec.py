"""Per-frame compression of large camera arrays (lz4 or zstd).

Each observation frame is its own blob, so sampling one transition decompresses exactly the
two frames it needs. Compressor objects are kept per thread: zstd's are not thread-safe, and
batches are gathered outside the store lock.
"""
from __future__ import annotations

import threading

import numpy as np


class FrameCodec:
    def __init__(self, kind: str = "none", level: int = 1):
        if kind not in ("none", "lz4", "zstd"):
            raise ValueError(f"unknown compression {kind!r}")
        self.kind, self.level = kind, level
        self._local = threading.local()

    @property
    def enabled(self) -> bool:
        return self.kind != "none"

    def compress(self, frame: np.ndarray) -> bytes:
        data = np.ascontiguousarray(frame).reshape(-1).view(np.uint8)
        if self.kind == "lz4":
            import lz4.block

            return lz4.block.compress(data, store_size=True)
        c = getattr(self._local, "c", None)
        if c is None:
            import zstandard

            c = self._local.c = zstandard.ZstdCompressor(level=self.level)
        return c.compress(data)

    def decompress_into(self, blob: bytes, out: np.ndarray) -> None:
        if self.kind == "lz4":
            import lz4.block

            raw = lz4.block.decompress(blob)
        else:
            d = getattr(self._local, "d", None)
            if d is None:
                import zstandard

                d = self._local.d = zstandard.ZstdDecompressor()
            raw = d.decompress(blob)
        out.reshape(-1).view(np.uint8)[:] = np.frombuffer(raw, dtype=np.uint8)
