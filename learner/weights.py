"""Weight broadcast: a versioned publish after every K updates, plus a queryable for late joiners.

Publishing uses congestion control DROP (a slow actor must never stall training); an actor
that missed a version simply takes the next one, and one that starts late asks the
queryable for the latest at once.
"""

from __future__ import annotations

import threading
import time

import torch
import zenoh

from protocol import keys
from protocol.messages import WeightsUpdate, encode


class WeightsPublisher:
    """Owns the weights key of a run: publishes new versions and answers ``get`` with the latest."""

    def __init__(self, session: zenoh.Session, run_id: str, config_digest: str = ""):
        self._key = keys.weights(run_id)
        self._digest = config_digest
        self._publisher = session.declare_publisher(self._key, congestion_control=zenoh.CongestionControl.DROP)
        self._lock = threading.Lock()
        self._latest: bytes | None = None
        self.version = 0
        self._queryable = session.declare_queryable(self._key, self._answer)

    def publish(self, weights: dict[str, torch.Tensor], version: int, learner_step: int, env_steps: int = 0) -> int:
        """Encode and broadcast ``weights`` as ``version``; returns the message size in bytes.

        ``env_steps``: transitions the replay had received (demos included), for learning curves.
        """
        tensors = {name: t.detach().float().cpu().numpy() for name, t in weights.items()}
        update = WeightsUpdate(version, learner_step, tensors, self._digest, published_at=time.time(),
                               env_steps=env_steps)
        payload = encode(update)
        with self._lock:
            self._latest, self.version = payload, version
        self._publisher.put(payload)
        return len(payload)

    def _answer(self, query: zenoh.Query) -> None:
        with self._lock:
            latest = self._latest
        if latest is not None:
            query.reply(self._key, latest)

    def close(self) -> None:
        self._queryable.undeclare()
        self._publisher.undeclare()

