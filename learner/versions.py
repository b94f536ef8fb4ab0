"""The last weights version this run's learner published, kept on disk so a restart never reuses one.

A checkpoint records the version it was taken at, but the learner goes on publishing after
it; resuming from the checkpoint alone would publish those numbers again with other weights.
:meth:`PublishedVersion.record` writes the number atomically (temp file, fsync, rename)
*before* the version goes on the wire, so a crash between the two can skip a number but
never repeat one. On restart the learner continues from ``max(checkpoint, recorded) + 1``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)


class PublishedVersion:
    """``<run_dir>/learner/published_version``: one integer, the highest version sent so far."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def read(self) -> int:
        """The recorded version; 0 when none was ever recorded (or the file cannot be read, logged)."""
        try:
            text = self.path.read_text().strip()
        except FileNotFoundError:
            return 0
        except OSError as exc:
            log.error("cannot read %s (%s): weights versions may repeat after this restart", self.path, exc)
            return 0
        if not text.isdigit():
            log.error("%s holds %r, not a version: weights versions may repeat after this restart", self.path, text)
            return 0
        return int(text)

    def record(self, version: int) -> None:
        """Durably remember ``version`` (call before publishing it; raises OSError when it cannot)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        with open(tmp, "w") as f:
            f.write(f"{int(version)}\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path)
        fd = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
