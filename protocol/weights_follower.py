"""The actor's side of the weight broadcast: follow the learner's versions, swap between episodes.

Every weights message is hostile until checked: it must decode, carry our network digest
and only finite numbers, and (when the caller loads it) fit the networks. Which version is
current is the learner's word, not the message's: the learner announces each version in
its heartbeat (``status/learner/*``, counter ``weights_version``) before sending it, and a
pushed or queried update is taken only if its version is at most the announced one. So a
forged or replayed message with a huge version is ignored instead of freezing the actor,
and if one was taken before any announcement arrived (or the learner was reset), the
follower resyncs down to the learner's version as soon as it hears one, asking the
learner's queryable when it holds nothing suitable. With no announcement heard yet, any
newer version is taken (an actor must be able to start before the learner's first status).
An update that arrives before its announcement (the status was dropped) is counted as
``not_announced`` and fetched from the queryable once the announcement comes.

Rejections are counted by reason (``rejected_by``) for the actor's status. Nothing here
raises into Zenoh's callbacks or the actor loop: every failure is logged and counted.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from typing import Callable

import numpy as np
import torch
import zenoh

from protocol import keys
from protocol.codec import ProtocolError
from protocol.messages import Status, WeightsUpdate, decode

log = logging.getLogger(__name__)

#: Why a weights update was not taken.
REASONS = ("decode_error", "bad_digest", "non_finite", "not_announced", "older", "bad_tensors", "internal_error")


class WeightsFollower:
    """Keeps the last few received payloads (decoded lazily) and picks the one to swap in.

    The Zenoh callback only keeps a reference, so a burst of versions costs nothing; the
    actor calls :meth:`newer` when it is ready to swap (between episodes), then
    :meth:`adopt` to load the update and make it current.
    """

    def __init__(self, session: zenoh.Session, run_id: str, expected_digest: str = "",
                 resync_every_s: float = 2.0, query_timeout_s: float = 1.0, inbox_size: int = 4):
        self._key = keys.weights(run_id)
        self._run_id = run_id
        self._session = session
        self._digest = expected_digest
        self._lock = threading.Lock()
        self._inbox: deque[tuple[bytes, float]] = deque(maxlen=inbox_size)  #: (payload, wall clock at receipt)
        self._resync_every_s, self._query_timeout_s = resync_every_s, query_timeout_s
        self._last_query = -math.inf
        self.version = 0  #: version currently in use (0 = none yet); set by :meth:`adopt`
        self.announced: int | None = None  #: the version the learner's heartbeat last named
        self.rejected_by = dict.fromkeys(REASONS, 0)  #: updates not taken, by reason
        self.bad_announcements = 0  #: learner status messages that could not be read
        self.superseded = 0  #: payloads pushed out of the inbox unread by newer ones (a burst, or a flood)
        self.latency_s = 0.0  #: publish-to-receipt delay of the newest update (wall clocks; same host or NTP)
        self._subscriber = session.declare_subscriber(self._key, self._on_sample)
        self._status = session.declare_subscriber(keys.status(run_id, "learner", "*"), self._on_status)

    @property
    def rejected(self) -> int:
        """Updates not taken, all reasons together."""
        return sum(self.rejected_by.values())

    def counters(self) -> dict[str, float]:
        """For the actor's status: ``weights_rejected_<reason>`` and the learner's announced version."""
        out = {f"weights_rejected_{reason}": n for reason, n in self.rejected_by.items()}
        out["weights_announced"] = -1 if self.announced is None else self.announced
        out["weights_superseded"] = self.superseded
        out["weights_bad_announcements"] = self.bad_announcements
        return out

    def reject(self, reason: str, detail: str = "") -> None:
        """Count (and log, sparsely) an update not taken; also for callers whose load failed."""
        self.rejected_by[reason] = n = self.rejected_by.get(reason, 0) + 1
        if n <= 3 or n % 100 == 0:
            log.warning("ignored a weights update (%s, %d so far)%s", reason, n, f": {detail}" if detail else "")

    # -- receiving (Zenoh threads) -------------------------------------------------------
    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            payload = sample.payload.to_bytes()
            with self._lock:
                if len(self._inbox) == self._inbox.maxlen:
                    self.superseded += 1
                self._inbox.append((payload, time.time()))
        except Exception as exc:  # never raise into Zenoh
            self.reject("internal_error", repr(exc))

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            _, instance = keys.parse_role_instance(str(sample.key_expr))
            status = decode(sample.payload.to_bytes(), expect=Status)
            if (status.role, status.instance, status.run_id) != ("learner", instance, self._run_id):
                raise ProtocolError("status", f"sent on {sample.key_expr} but names {status.role}/{status.instance}")
            version = status.counters.get("weights_version")
            if version is None:
                return
            if not (math.isfinite(version) and version >= 0 and version == int(version)):
                raise ProtocolError("counters.weights_version", f"{version} is not a version")
            self.announced = int(version)
        except Exception as exc:  # ProtocolError, ValueError from the key, or anything else: count, never raise
            self.bad_announcements += 1
            if self.bad_announcements <= 3 or self.bad_announcements % 100 == 0:
                log.warning("ignored a learner status (%d so far): %s", self.bad_announcements, exc)

    def fetch_latest(self, timeout_s: float) -> None:
        """Ask the learner's queryable for the newest weights (a late joiner need not wait); replies join the inbox."""
        try:
            for reply in self._session.get(self._key, timeout=timeout_s):
                if reply.ok is not None:
                    self._on_sample(reply.ok)
        except zenoh.ZError as exc:
            log.info("weights query failed: %s", exc)

    # -- choosing (the actor's thread) ---------------------------------------------------
    def newer(self) -> WeightsUpdate | None:
        """The update to swap in now, or None: the highest acceptable version received.

        When nothing received is acceptable but the learner announced a version other than
        the one in use, ask the learner's queryable (at most every ``resync_every_s``).
        """
        try:
            update = self._choose(self._drain())
            if update is None and self.announced is not None and self.announced != self.version:
                now = time.monotonic()
                if now - self._last_query >= self._resync_every_s:
                    self._last_query = now
                    self.fetch_latest(self._query_timeout_s)
                    update = self._choose(self._drain())
            return update
        except Exception as exc:  # a bug here must not take the actor down
            log.exception("choosing weights failed")
            self.reject("internal_error", repr(exc))
            return None

    def adopt(self, update: WeightsUpdate, load: Callable[[dict[str, torch.Tensor]], None]) -> bool:
        """``load`` the update's tensors and make its version current; False (counted) when they do not fit."""
        try:
            load(tensors_from_update(update))
        except ValueError as exc:
            self.reject("bad_tensors", str(exc))
            return False
        self.version = update.version
        return True

    def _drain(self) -> list[tuple[bytes, float]]:
        with self._lock:
            inbox = list(self._inbox)
            self._inbox.clear()
        return inbox

    def _choose(self, inbox: list[tuple[bytes, float]]) -> WeightsUpdate | None:
        best: tuple[WeightsUpdate, float] | None = None
        for payload, received_at in inbox:
            update = self._check(payload)
            if update is None:
                continue
            reason = self._verdict(update.version)
            if reason == "same":
                continue
            if reason:
                self.reject(reason, f"version {update.version} (in use {self.version}, announced {self.announced})")
                continue
            if best is None or update.version >= best[0].version:  # equal versions: the later copy
                best = (update, received_at)
        if best is None:
            return None
        update, received_at = best
        if update.published_at:
            self.latency_s = max(0.0, received_at - update.published_at)
        return update

    def _check(self, payload: bytes) -> WeightsUpdate | None:
        """The decoded update if it is well-formed, ours and finite, else None (counted)."""
        try:
            update = decode(payload, expect=WeightsUpdate)
        except ProtocolError as exc:
            # The codec refuses NaN/inf itself; its reason text is the only way to tell that apart.
            self.reject("non_finite" if "NaN" in exc.reason else "decode_error", str(exc))
            return None
        except Exception as exc:  # decode must raise only ProtocolError; if it does not, still carry on
            log.exception("decoding a weights message failed unexpectedly")
            self.reject("internal_error", repr(exc))
            return None
        if self._digest and update.config_digest and update.config_digest != self._digest:
            self.reject("bad_digest", f"weights for another network config ({update.config_digest} != {self._digest})")
            return None
        bad = next((name for name, a in update.tensors.items() if not np.isfinite(a).all()), None)
        if bad is not None:  # the codec checks this too; weights are where NaN would do most harm
            self.reject("non_finite", f"version {update.version}: {bad} holds NaN or inf")
            return None
        return update

    def _verdict(self, version: int) -> str:
        """"" to take ``version``, "same" to pass over it silently, else the reason it is refused."""
        current, announced = self.version, self.announced
        if announced is None:  # nothing heard from the learner yet: trust newer versions
            return "" if version > current else ("same" if version == current else "older")
        if version > announced:
            return "not_announced"
        if current > announced:  # in use is a version the learner never announced: resync down
            return "" if version >= 1 else "older"
        return "" if version > current else ("same" if version == current else "older")

    def close(self) -> None:
        self._subscriber.undeclare()
        self._status.undeclare()


def tensors_from_update(update: WeightsUpdate) -> dict[str, torch.Tensor]:
    """The received arrays as torch tensors (copies, so the message buffer can be freed)."""
    return {name: torch.from_numpy(np.array(a, copy=True)) for name, a in update.tensors.items()}
