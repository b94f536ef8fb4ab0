"""Counting what a receiver refuses, by reason, with rate-limited log lines.

A hostile or buggy sender can produce thousands of bad messages a second; each one is
counted (``<prefix>_<reason>`` in the replay's status counters) but at most one log line
per reason per ``interval_s`` is written, naming how many were silenced since the last one.
Reason names are sanitised and capped, so no sender can grow the status message.
"""
from __future__ import annotations

import collections
import logging
import re
import threading
import time
from typing import Optional

from protocol.codec import ProtocolError

_UNSAFE = re.compile(r"[^a-z0-9_]+")
MAX_REASONS = 64  #: distinct reasons per counter; later ones count as "other"


class ReasonCounter:
    """``count(reason, detail)``: increments ``stats[f"{prefix}_{reason}"]`` and the legacy total."""

    def __init__(self, stats: collections.Counter, prefix: str, known: tuple[str, ...] = (),
                 total: Optional[str] = None, interval_s: float = 5.0, logger: Optional[logging.Logger] = None):
        self.stats, self.prefix, self.total = stats, prefix, total
        self.interval_s = float(interval_s)
        self.log = logger or logging.getLogger("replay_server")
        self._lock = threading.Lock()
        self._reasons: set[str] = set()
        self._last_log: dict[str, float] = {}
        self._silenced: collections.Counter = collections.Counter()
        self.last: str = ""
        for reason in known:  # present from the start: stable series for dashboards and alerts
            self._reasons.add(reason)
            stats.setdefault(f"{prefix}_{reason}", 0)
        if total:
            stats.setdefault(total, 0)

    def name(self, reason: str) -> str:
        return f"{self.prefix}_{self._reason(reason)}"

    def _reason(self, reason: str) -> str:
        reason = _UNSAFE.sub("_", str(reason).lower()).strip("_")[:48] or "other"
        if reason not in self._reasons:
            if len(self._reasons) >= MAX_REASONS:
                return "other"
            self._reasons.add(reason)
        return reason

    def count(self, reason: str, detail: str = "", sender: str = "", exc_info: bool = False) -> None:
        with self._lock:
            reason = self._reason(reason)
            self.stats[f"{self.prefix}_{reason}"] += 1
            if self.total:
                self.stats[self.total] += 1
            self.last = f"{reason}: {detail}"[:200]
            now = time.monotonic()
            if now - self._last_log.get(reason, -1e9) < self.interval_s:
                self._silenced[reason] += 1
                return
            self._last_log[reason] = now
            silenced = self._silenced.pop(reason, 0)
        more = f" (+{silenced} more since the last line)" if silenced else ""
        self.log.warning("%s %s%s: %s%s", self.prefix.replace("_", " "), reason,
                         f" from {sender}" if sender else "", detail[:300], more, exc_info=exc_info)

    def error(self, exc: BaseException, detail: str = "") -> None:
        """An exception that reached a generic handler: counted by its type, logged with its traceback."""
        self.count(type(exc).__name__, f"{detail}: {exc!r}" if detail else repr(exc), exc_info=True)


def protocol_reason(exc: ProtocolError) -> str:
    """The rejection reason of a ProtocolError: ``decode``, ``too_large``, ``nonfinite``, ``bad_id`` or ``schema``.

    Uses the error's own ``code``/``category`` when the protocol sets one, else its field and text."""
    for attr in ("code", "category", "kind"):
        code = getattr(exc, attr, None)
        if isinstance(code, str) and code:
            return code
    field = str(getattr(exc, "field", "")).lower()
    text = str(getattr(exc, "reason", exc)).lower()
    if "finite" in text or "nan" in text.split():
        return "nonfinite"
    if "exceeds" in text or "too large" in text or "too many" in text or "limit" in text:
        return "too_large"
    if field.startswith(("frame", "batch", "message")) or any(
            w in text for w in ("malformed", "truncated", "offset", "do not hold", "disagree", "undecodable")):
        return "decode"
    if field in ("actor_id", "episode_id", "run_id", "instance"):
        return "bad_id"
    if "an episode has" in text and ("steps" in text or "cameras" in text):
        return "too_large"
    return "schema"
