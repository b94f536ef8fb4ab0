"""The Zenoh router role: the hub every other role connects to (no zenohd binary needed).

It opens a router-mode session listening on ``fabric.listen`` and, like every role,
declares a liveliness token and publishes its status once a second.
"""

from __future__ import annotations

import logging

from protocol.fabric import FabricConfig, open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext

log = logging.getLogger(__name__)


def run(config: FabricConfig, ctx: RoleContext) -> int:
    session = open_session(config, "router")
    log.info("zenoh router listening on %s", ", ".join(config.listen))
    heartbeat = Heartbeat(session, ctx.run_id, "router", ctx.instance, info=lambda: {"listen": ",".join(config.listen)})
    try:
        while not ctx.stop.wait(0.5):
            pass
    finally:
        heartbeat.close()
        session.close()
    return 0
