"""Who sent an episode: the actor id in its key expression, and its Zenoh source when known.

On an unauthenticated fabric an id is only a claim. Two things make claims checkable here:

- the key's actor segment must pass ``protocol.keys.check_id`` (no ``*``, ``$``, ``/``) and
  equal the episode's ``actor_id``; acks are only ever published on a key built from it;
- when a sample carries ``source_info`` (Zenoh 1.x sets it only when the publisher attaches
  one, e.g. ``SourceInfo(publisher.id, sn)``), the actor id is bound to that Zenoh session
  id while it keeps storing episodes; an episode claiming the id from another session
  within ``ttl_s`` of the bound one's last store is impersonation. The binding is released
  when the actor's liveliness token goes away (its process or session ended), so a
  restarted actor (a new session id) gets its id back at once; otherwise (a token that
  never existed, or a lost DELETE) it expires after ``ttl_s``. source_info is
  itself sent by the publisher, so this stops mistakes and casual spoofing, not a
  determined attacker: that needs Zenoh TLS and access control (see docs/trust.md).
"""
from __future__ import annotations

import threading
import time
from collections import OrderedDict
from typing import Optional

from protocol import keys


def key_actor(key_expr, run_id: str) -> str:
    """The checked actor id of an episode key ``c2farm/<run>/episodes/<actor>``; ValueError otherwise."""
    text = str(key_expr)
    prefix = keys.episodes(run_id, "*")[:-1]
    if not text.startswith(prefix):
        raise ValueError(f"not an episode key: {text[:200]!r}")
    return keys.check_id(text[len(prefix):], "actor")


def source_zid(sample) -> Optional[str]:
    """The Zenoh session id the publisher attached to ``sample``, or None."""
    try:
        info = sample.source_info
        return None if info is None else str(info.source_id.zid)
    except Exception:  # unstable API: absence or a change must not break ingest
        return None


class SourceBindings:
    """actor id -> (Zenoh session id, last store time), bounded, expiring after ``ttl_s``."""

    def __init__(self, ttl_s: float, max_ids: int):
        self.ttl_s, self.max_ids = float(ttl_s), max(1, int(max_ids))
        self._bound: OrderedDict[str, tuple[str, float]] = OrderedDict()
        self._lock = threading.Lock()

    def owner(self, actor: str, zid: Optional[str]) -> Optional[str]:
        """The session ``actor`` is bound to if ``zid`` is another one (impersonation), else None.

        A claim without a source is not judged: there is nothing to compare."""
        if zid is None:
            return None
        with self._lock:
            bound = self._bound.get(actor)
            if bound is None or bound[0] == zid or time.monotonic() - bound[1] > self.ttl_s:
                return None
            return bound[0]

    def stored(self, actor: str, zid: Optional[str]) -> None:
        """An episode from ``zid`` was stored under ``actor``: (re)bind and refresh."""
        if zid is None:
            return
        with self._lock:
            bound = self._bound.get(actor)
            if bound is not None and bound[0] != zid and time.monotonic() - bound[1] <= self.ttl_s:
                return  # raced with the owner: the live binding stays
            self._bound[actor] = (zid, time.monotonic())
            self._bound.move_to_end(actor)
            while len(self._bound) > self.max_ids:
                self._bound.popitem(last=False)

    def release(self, actor: str) -> bool:
        """Forget ``actor``'s binding (its session is gone); True if there was one."""
        with self._lock:
            return self._bound.pop(actor, None) is not None

    def __len__(self) -> int:
        return len(self._bound)
