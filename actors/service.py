"""The actor role (shell): joins the fabric, reports status, stops cleanly.

Stepping the PyBullet task is not wired in yet; a later issue replaces this body.
"""

from __future__ import annotations

from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext


def run(config, ctx: RoleContext) -> int:
    session = open_session(ctx.fabric)
    heartbeat = Heartbeat(session, ctx.run_id, "actor", ctx.instance, info=lambda: {"stage": "shell"})
    try:
        while not ctx.stop.wait(0.5):
            pass
    finally:
        heartbeat.close()
        session.close()
    return 0
