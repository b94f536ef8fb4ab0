"""Weight broadcast: a versioned publish after every K updates, plus a queryable for late joiners.

Publishing uses congestion control DROP (a slow actor must never stall training); an actor
that missed a version simply takes the next one, and one that starts late asks the
queryable for the latest at once.

What goes out is checked here, at the boundary: a snapshot with a NaN or inf tensor is
refused (counted in ``refused``, nothing sent, the queryable keeps the last good one), and
a version is only ever sent once, increasing (the learner keeps that true across restarts,
``learner/versions.py``).
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import torch
import zenoh

from protocol import keys
from protocol.messages import WeightsUpdate, encode

log = logging.getLogger(__name__)


class WeightsPublisher:
    """Owns the weights key of a run: publishes new versions and answers ``get`` with the latest."""

    def __init__(self, session: zenoh.Session, run_id: str, config_digest: str = ""):
        self._key = keys.weights(run_id)
        self._digest = config_digest
        self._publisher = session.declare_publisher(self._key, congestion_control=zenoh.CongestionControl.DROP)
        self._lock = threading.Lock()
        self._latest: bytes | None = None
        self.version = 0  #: last version sent
        self.refused = 0  #: snapshots refused for non-finite tensors
        self._queryable = session.declare_queryable(self._key, self._answer)

    def encode(self, weights: dict[str, torch.Tensor], version: int, learner_step: int,
               env_steps: int = 0) -> bytes | None:
        """The message for ``weights`` as ``version``, or None (counted) when a tensor is non-finite.

        ``env_steps``: transitions the replay had received (demos included), for learning curves.
        Raises ValueError for a version not above the last one sent (a bug, not bad data).
        """
        if version <= self.version:
            raise ValueError(f"weights version {version} after {self.version}: versions only grow")
        tensors = {name: t.detach().float().cpu().numpy() for name, t in weights.items()}
        bad = [name for name, a in tensors.items() if not np.isfinite(a).all()]
        if bad:
            self.refused += 1
            log.error("refusing to publish weights version %d: non-finite values in %d tensors, e.g. %s",
                      version, len(bad), bad[0])
            return None
        return encode(WeightsUpdate(version, learner_step, tensors, self._digest, published_at=time.time(),
                                    env_steps=env_steps))

    def send(self, payload: bytes, version: int) -> None:
        """Broadcast an :meth:`encode`-d message and keep it for the queryable."""
        with self._lock:
            self._latest, self.version = payload, version
        self._publisher.put(payload)

    def publish(self, weights: dict[str, torch.Tensor], version: int, learner_step: int, env_steps: int = 0) -> int:
        """Encode and send in one go; returns the message size in bytes (0: refused, nothing sent)."""
        payload = self.encode(weights, version, learner_step, env_steps)
        if payload is None:
            return 0
        self.send(payload, version)
        return len(payload)

    def _answer(self, query: zenoh.Query) -> None:
        with self._lock:
            latest = self._latest
        if latest is not None:
            query.reply(self._key, latest)

    def close(self) -> None:
        self._queryable.undeclare()
        self._publisher.undeclare()
