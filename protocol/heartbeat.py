"""A role's presence on the fabric: a liveliness token plus a status message every second.

The token vanishes the moment the role's session dies (even on SIGKILL, once the router
notices the dropped link), which is how the dashboard tells "gone" from "quiet".
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from typing import Callable

import zenoh

from protocol import keys
from protocol.limits import DEFAULT_LIMITS as LIMITS
from protocol.messages import Status, encode

log = logging.getLogger(__name__)


class Heartbeat:
    """Declares ``alive/<role>/<instance>`` and publishes ``Status`` from ``counters()``.

    ``counters`` and ``info`` are called from the heartbeat thread; they should return
    quickly (copy a few numbers), never block.
    """

    def __init__(
        self,
        session: zenoh.Session,
        run_id: str,
        role: str,
        instance: str,
        counters: Callable[[], dict[str, float]] = dict,
        info: Callable[[], dict[str, str]] = dict,
        period_s: float = 1.0,
    ):
        self.run_id, self.role, self.instance = run_id, keys.check_id(role), keys.check_id(instance)
        self._counters, self._info, self._period = counters, info, period_s
        self.state = "running"
        self._token = session.liveliness().declare_token(keys.alive(run_id, role, instance))
        self._publisher = session.declare_publisher(
            keys.status(run_id, role, instance), congestion_control=zenoh.CongestionControl.DROP
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"heartbeat-{instance}", daemon=True)
        self._thread.start()

    def status(self) -> Status:
        return Status(
            role=self.role,
            instance=self.instance,
            run_id=self.run_id,
            pid=os.getpid(),
            host=socket.gethostname(),
            time=time.time(),
            state=self.state,
            counters=_bounded({str(k)[: LIMITS.max_name]: float(v) for k, v in self._counters().items()}),
            info=_bounded({str(k)[: LIMITS.max_name]: str(v)[: LIMITS.max_text] for k, v in self._info().items()}),
        )

    def publish(self) -> None:
        """Send one status now (also called by the thread every period)."""
        try:
            self._publisher.put(encode(self.status()))
        except Exception:  # a heartbeat must never take its role down
            log.exception("heartbeat of %s/%s failed", self.role, self.instance)

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            self.publish()

    def close(self, state: str = "stopped") -> None:
        """Publish a last status with ``state`` and withdraw the liveliness token."""
        self._stop.set()
        self._thread.join(timeout=2 * self._period)
        self.state = state
        self.publish()
        self._publisher.undeclare()
        self._token.undeclare()


def _bounded(items: dict) -> dict:
    """At most ``max_items`` entries, so a long error text or a growing counter set truncates
    the heartbeat instead of getting it refused (and the role shown as silent)."""
    return dict(list(items.items())[: LIMITS.max_items])
