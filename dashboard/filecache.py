"""Reading run files cheaply: a value is recomputed only when the files it came from change.

The dashboard polls; the roles write. Every answer built from files is memoised under the
files' ``(inode, mtime_ns, size)`` stamps, so a repeated poll costs a few ``stat`` calls and
no parsing, and the stamp doubles as the HTTP ETag (a browser revalidating gets a 304).
:class:`CsvTail` goes one step further for the append-only metric CSVs: it parses only the
bytes appended since the last read.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable, Hashable, Iterable

Stamp = tuple[int, int, int] | None


def stamp(path: Path) -> Stamp:
    """(inode, mtime_ns, size) of ``path``, None if it does not exist."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def etag_of(key: Hashable) -> str:
    return '"' + hashlib.blake2b(repr(key).encode(), digest_size=8).hexdigest() + '"'


class FileCache:
    """Memoises ``compute()`` under a key, usually the stamps of the files it reads (thread-safe)."""

    def __init__(self, max_entries: int = 64) -> None:
        self._lock = threading.Lock()
        self._entries: OrderedDict[Hashable, Any] = OrderedDict()
        self.max_entries = max_entries
        self.computed = 0  #: times a value was (re)computed: tests check that polls hit the cache

    def get(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        with self._lock:
            if key in self._entries:
                self._entries.move_to_end(key)
                return self._entries[key]
        value = compute()  # outside the lock: a slow file read must not block other endpoints
        with self._lock:
            self.computed += 1
            self._entries[key] = value
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)
        return value

    def for_files(self, name: str, paths: Iterable[Path], compute: Callable[[], Any]) -> tuple[Any, str]:
        """``compute()`` memoised under ``name`` and the stamps of ``paths``; returns (value, etag)."""
        key = (name, tuple((str(p), stamp(p)) for p in paths))
        return self.get(key, compute), etag_of(key)


class CsvTail:
    """An append-only CSV of numbers (header first), parsed incrementally.

    Cells become floats; empty, unparsable or non-finite cells become None. A partly written
    last line is left for the next read. A file that shrank or was replaced is read afresh.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._reset(None)

    def _reset(self, inode: int | None) -> None:
        self.header: list[str] = []
        self.rows: list[list[float | None]] = []
        self._offset = 0
        self._inode = inode

    def read(self) -> tuple[list[str], list[list[float | None]]]:
        """(header, rows) as of now; rows with the wrong number of cells are skipped."""
        with self._lock:
            st = stamp(self.path)
            if st is None:
                self._reset(None)
                return [], []
            inode, _, size = st
            if inode != self._inode or size < self._offset:
                self._reset(inode)
            if size > self._offset:
                with self.path.open("rb") as f:
                    f.seek(self._offset)
                    data = f.read(size - self._offset)
                end = data.rfind(b"\n") + 1  # complete lines only
                self._offset += end
                self._parse(data[:end].decode("utf-8", errors="replace"))
            return self.header, self.rows

    def _parse(self, text: str) -> None:
        for cells in csv.reader(io.StringIO(text)):
            if not cells:
                continue
            if not self.header:
                self.header = [c.strip() for c in cells]
            elif len(cells) == len(self.header):
                self.rows.append([_number(c) for c in cells])


def _number(cell: str) -> float | None:
    try:
        value = float(cell)
    except ValueError:
        return None
    return value if math.isfinite(value) else None
