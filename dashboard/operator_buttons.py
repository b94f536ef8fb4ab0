"""The operator's buttons for a robot actor: ``POST /api/operator/<actor>/<action>``.

Actions are ``success``, ``fail``, ``reset_done``, ``stop`` and ``resume``
(``protocol.messages.OperatorAction``). Each press becomes one validated ``OperatorCommand``
put on ``c2farm/<run>/operator/<actor>``, which that robot actor subscribes to. The HTTP side
holds no Zenoh: the dashboard role installs an ``OperatorPublisher`` as
``app.state.operator`` once its session is open; until then the routes answer 503. A press
moves an arm: it always needs the dashboard's token (``Authorization: Bearer``), wherever the
dashboard binds; :mod:`dashboard.access`'s middleware in :func:`dashboard.app.create_app` checks it.
"""

from __future__ import annotations

import itertools
import threading
import time

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import JSONResponse

from protocol import keys
from protocol.messages import OperatorAction, OperatorCommand, encode

router = APIRouter()


class OperatorPublisher:
    """Puts operator commands on the fabric, numbered in the order they were pressed."""

    def __init__(self, session, run_id: str) -> None:
        self.session, self.run_id = session, run_id
        self._seq = itertools.count(1)
        self._lock = threading.Lock()

    def send(self, actor: str, action: OperatorAction, source: str = "dashboard") -> OperatorCommand:
        with self._lock:
            command = OperatorCommand(actor, action, next(self._seq), time.time(), source)
        self.session.put(keys.concrete(keys.operator(self.run_id, actor)), encode(command))
        return command


@router.post("/api/operator/{actor}/{action}")
def press(actor: str, action: str, request: Request) -> JSONResponse:
    """One button press for one robot actor; 202 once it is on the fabric."""
    publisher: OperatorPublisher | None = getattr(request.app.state, "operator", None)
    if publisher is None:
        raise HTTPException(503, "the operator channel is not connected yet")
    if not keys.is_valid_id(actor):
        raise HTTPException(404, f"no such actor name {actor[:80]!r}")
    try:
        chosen = OperatorAction(action)
    except ValueError:
        raise HTTPException(
            404, f"unknown action {action[:40]!r}; one of {[a.value for a in OperatorAction]}"
        ) from None
    command = publisher.send(actor, chosen)
    return JSONResponse({"actor": actor, "action": chosen.value, "seq": command.seq}, status_code=202)
