"""Write-ahead log: every accepted episode is appended (and fsynced) before it is acked.

An ack therefore means "on disk": after a SIGKILL the server restores its latest checkpoint
and replays the log segments written since, so nothing acknowledged is lost. Segments are
``wal-<seq>.log``; a checkpoint rotates to a new segment at its snapshot and records that
sequence number; segments older than the oldest kept checkpoint are deleted.

Record layout: ``b"WAL1" | u32 crc32(payload) | u64 length | payload`` (the payload is the
episode message exactly as received). A torn tail (the process died mid-write) fails its
length or CRC check and ends that segment's replay: it was never acked.
"""
from __future__ import annotations

import logging
import os
import re
import struct
import zlib
from pathlib import Path
from typing import Iterator

log = logging.getLogger(__name__)

_REC = struct.Struct("<4sIQ")
_MAGIC = b"WAL1"
_NAME = re.compile(r"^wal-(\d{8})\.log$")


def segment_path(directory: Path, seq: int) -> Path:
    return Path(directory) / f"wal-{seq:08d}.log"


def list_segments(directory: Path) -> list[int]:
    directory = Path(directory)
    if not directory.is_dir():
        return []
    return sorted(int(m.group(1)) for p in directory.iterdir() if (m := _NAME.match(p.name)))


def read_segment(path: Path) -> Iterator[bytes]:
    """Yield the intact records of one segment, stopping at a torn or corrupt tail."""
    with open(path, "rb") as f:
        while True:
            head = f.read(_REC.size)
            if not head:
                return
            if len(head) < _REC.size:
                log.warning("%s: torn record header at the tail (never acked); ignored", path)
                return
            magic, crc, length = _REC.unpack(head)
            if magic != _MAGIC:
                log.warning("%s: bad record magic; the rest of the segment is ignored", path)
                return
            payload = f.read(length)
            if len(payload) < length or zlib.crc32(payload) != crc:
                log.warning("%s: torn or corrupt record at the tail (never acked); ignored", path)
                return
            yield payload


class WriteAheadLog:
    def __init__(self, directory: Path, fsync: bool = True):
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.fsync = fsync
        existing = list_segments(self.directory)
        self.seq = (existing[-1] + 1) if existing else 0
        self._file = open(segment_path(self.directory, self.seq), "ab")
        self._fsync_dir()
        self.bytes_since_rotate = 0

    def _fsync_dir(self) -> None:
        fd = os.open(self.directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def append(self, payloads: list[bytes]) -> None:
        """Append records and make them durable (one flush + fsync for the whole group)."""
        for p in payloads:
            self._file.write(_REC.pack(_MAGIC, zlib.crc32(p), len(p)))
            self._file.write(p)
            self.bytes_since_rotate += _REC.size + len(p)
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())

    def rotate(self) -> int:
        """Start a new segment; returns its sequence number (records before it are in older ones)."""
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())
        self._file.close()
        self.seq += 1
        self._file = open(segment_path(self.directory, self.seq), "ab")
        self._fsync_dir()
        self.bytes_since_rotate = 0
        return self.seq

    def delete_before(self, seq: int) -> None:
        for s in list_segments(self.directory):
            if s < seq:
                segment_path(self.directory, s).unlink(missing_ok=True)

    def close(self) -> None:
        if not self._file.closed:
            self._file.flush()
            if self.fsync:
                os.fsync(self._file.fileno())
            self._file.close()
