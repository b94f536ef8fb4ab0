"""At-least-once delivery of episodes to the replay server.

Every episode stays in a bounded outbox until the replay server acknowledges it (stored or
duplicate); unacknowledged ones are resent, so a replay restart loses nothing. The replay
stores each (actor id, episode id) once, which turns at-least-once into exactly-once.

An ack retires an episode only if it names that episode's payload digest: a stale ack, or
one forged by a client that never saw the payload, is counted (``forged_acks``) and
ignored, and the episode stays pending. (A client that can read the episodes key can still
compute the digest: on an unauthenticated fabric only Zenoh's access control stops that.)
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

import zenoh

from protocol import keys
from protocol.codec import ProtocolError, payload_digest
from protocol.episode import Episode
from protocol.messages import AckStatus, EpisodeAck, decode, encode

log = logging.getLogger(__name__)


@dataclass
class _Pending:
    """An episode sent and not yet acknowledged."""

    payload: bytes
    digest: str  #: payload_digest(payload): the one an ack must name
    sent: float  #: monotonic time of the last send


class Outbox:
    """Publishes episodes on ``episodes/<actor>`` and tracks acks on ``acks/<actor>``."""

    def __init__(self, session: zenoh.Session, run_id: str, actor_id: str, size: int = 16,
                 resend_after_s: float = 10.0, wait_s: float = 30.0, stop: threading.Event | None = None):
        self.actor_id = actor_id
        self._stop = stop  #: set when the role must stop: a full outbox then stops waiting for room
        self._size, self._resend_after, self._wait = size, resend_after_s, wait_s
        self._publisher = session.declare_publisher(
            keys.episodes(run_id, actor_id), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._pending: OrderedDict[int, _Pending] = OrderedDict()  # episode id -> what waits for its ack
        self._cond = threading.Condition()
        self._sn = itertools.count()  # source sequence numbers: the replay binds our id to this session
        self.counters = {"sent": 0, "acked": 0, "duplicates": 0, "rejected": 0, "resent": 0, "dropped": 0,
                         "bad_acks": 0, "forged_acks": 0, "unmatched_acks": 0}
        self._subscriber = session.declare_subscriber(keys.acks(run_id, actor_id), self._on_ack)

    @property
    def pending(self) -> int:
        with self._cond:
            return len(self._pending)

    def send(self, episode: Episode) -> None:
        """Publish ``episode`` and keep it until acknowledged. Waits (bounded) when the outbox is full.

        While it waits it keeps resending what is due: after a replay or router restart the
        full outbox is exactly what must be resent, or no ack would ever make room.
        """
        payload = encode(episode)
        deadline = time.monotonic() + self._wait
        room = lambda: len(self._pending) < self._size  # noqa: E731
        while True:
            with self._cond:
                left = deadline - time.monotonic()
                if (
                    room()
                    or left <= 0
                    or self._cond.wait_for(room, timeout=min(left, max(0.1, self._resend_after / 2)))
                ):
                    break
            if self._stopping:
                break  # keep it without dropping another: the role exits within its grace period
            self.resend_due()
        with self._cond:
            while len(self._pending) >= self._size and not self._stopping:
                dropped, _ = self._pending.popitem(last=False)
                self.counters["dropped"] += 1
                log.warning("outbox full for %.0f s: dropped episode %d unacknowledged", self._wait, dropped)
            self._pending[episode.episode_id] = _Pending(payload, payload_digest(payload), time.monotonic())
        self._put(payload)
        self.counters["sent"] += 1

    @property
    def _stopping(self) -> bool:
        return self._stop is not None and self._stop.is_set()

    def _put(self, payload: bytes) -> None:
        """Publish with source info, so the replay can tell this session from one claiming our id."""
        self._publisher.put(payload, source_info=zenoh.SourceInfo(self._publisher.id, next(self._sn)))

    def resend_due(self) -> int:
        """Resend every episode unacknowledged for longer than ``resend_after_s``; returns how many."""
        now = time.monotonic()
        with self._cond:
            due = [entry for entry in self._pending.values() if now - entry.sent >= self._resend_after]
            for entry in due:
                entry.sent = now
        for entry in due:
            self._put(entry.payload)
        self.counters["resent"] += len(due)
        return len(due)

    def flush(self, timeout_s: float, stop: threading.Event | None = None) -> bool:
        """Wait until every episode is acknowledged (resending as due); True if the outbox emptied.

        Gives up early once ``stop`` is set, so a role told to stop stays inside the
        launcher's grace period (what is unacknowledged then was never promised stored).
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not (stop is not None and stop.is_set()):
            with self._cond:
                if self._cond.wait_for(lambda: not self._pending, timeout=min(0.5, self._resend_after)):
                    return True
            self.resend_due()
        return self.pending == 0

    def _on_ack(self, sample: zenoh.Sample) -> None:
        try:
            ack = decode(sample.payload.to_bytes(), expect=EpisodeAck)
        except ProtocolError as exc:
            self.counters["bad_acks"] += 1
            log.warning("ignored a malformed ack: %s", exc)
            return
        if ack.actor_id != self.actor_id:
            self.counters["unmatched_acks"] += 1
            return
        with self._cond:
            entry = self._pending.get(ack.episode_id)
            if entry is None:  # not pending (any more): e.g. the second ack of a resend
                self.counters["unmatched_acks"] += 1
                return
            if ack.digest != entry.digest:
                self.counters["forged_acks"] += 1
                if self.counters["forged_acks"] <= 3 or self.counters["forged_acks"] % 100 == 0:
                    log.warning("ignored an ack for episode %d that names another payload (%d so far)",
                                ack.episode_id, self.counters["forged_acks"])
                return
            del self._pending[ack.episode_id]
            self._cond.notify_all()
        if ack.status is AckStatus.STORED:
            self.counters["acked"] += 1
        elif ack.status is AckStatus.DUPLICATE:
            self.counters["duplicates"] += 1
        else:
            self.counters["rejected"] += 1
            log.error("replay rejected episode %d: %s", ack.episode_id, ack.reason)

    def close(self) -> None:
        self._subscriber.undeclare()
        self._publisher.undeclare()
