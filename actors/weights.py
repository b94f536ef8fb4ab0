"""The actor's side of the weight broadcast: keep the newest version, swap it in between episodes."""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import torch
import zenoh

from protocol import keys
from protocol.codec import ProtocolError
from protocol.messages import WeightsUpdate, decode

log = logging.getLogger(__name__)


class WeightsFollower:
    """Subscribes to the weights key and remembers only the newest payload (decoded lazily).

    The Zenoh callback just keeps a reference, so a burst of versions costs nothing; the
    actor decodes the newest one when it is ready to swap (between episodes).
    """

    def __init__(self, session: zenoh.Session, run_id: str, expected_digest: str = ""):
        self._key = keys.weights(run_id)
        self._session = session
        self._digest = expected_digest
        self._lock = threading.Lock()
        self._payload: bytes | None = None
        self._received_at = 0.0  #: wall clock at receipt of the held payload
        self.version = 0  #: version currently in use (0 = none yet)
        self.rejected = 0  #: malformed or incompatible updates seen
        self.latency_s = 0.0  #: publish-to-receipt delay of the newest update (wall clocks; same host or NTP)
        self._subscriber = session.declare_subscriber(self._key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self._payload, self._received_at = sample.payload.to_bytes(), time.time()

    def fetch_latest(self, timeout_s: float) -> None:
        """Ask the learner's queryable for the newest weights (a late joiner needs not wait)."""
        try:
            for reply in self._session.get(self._key, timeout=timeout_s):
                if reply.ok is not None:
                    self._on_sample(reply.ok)
        except zenoh.ZError as exc:
            log.info("weights query failed: %s", exc)

    def newer(self) -> WeightsUpdate | None:
        """The newest received update if it is newer than ``version``, else None."""
        with self._lock:
            payload, received_at, self._payload = self._payload, self._received_at, None
        if payload is None:
            return None
        try:
            update = decode(payload, expect=WeightsUpdate)
        except ProtocolError as exc:
            self.rejected += 1
            log.warning("rejected a weights update: %s", exc)
            return None
        if self._digest and update.config_digest and update.config_digest != self._digest:
            self.rejected += 1
            log.warning("rejected weights for another network config (%s != %s)", update.config_digest, self._digest)
            return None
        if update.version <= self.version:
            return None
        if update.published_at:
            self.latency_s = max(0.0, received_at - update.published_at)
        return update

    def close(self) -> None:
        self._subscriber.undeclare()


def tensors_from_update(update: WeightsUpdate) -> dict[str, torch.Tensor]:
    """The received arrays as torch tensors (copies, so the message buffer can be freed)."""
    return {name: torch.from_numpy(np.array(a, copy=True)) for name, a in update.tensors.items()}
