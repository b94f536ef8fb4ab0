"""The Zenoh router role: the hub every other role connects to (no zenohd binary needed).

It opens a router-mode session listening on ``fabric.listen`` and, like every role,
declares a liveliness token and publishes its status once a second. On a secure fabric it
also enforces the run's access rules (``deploy/access_control.py``) for every certificate
the run's authority signed in ``fabric.certs``.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from deploy.access_control import access_control, unknown_roles
from deploy.certs import certificate_names
from protocol.fabric import FabricConfig, open_session, zenoh_config
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext

log = logging.getLogger(__name__)


def run(config: FabricConfig, ctx: RoleContext) -> int:
    zconfig = zenoh_config(config, "router")
    if config.secure:
        names = certificate_names(Path(config.certs))
        for name in unknown_roles(names):
            log.warning("certificate %s names no role of ours: it may connect but do nothing", name)
        zconfig.insert_json5("access_control", json.dumps(access_control(ctx.run_id, names)))
        log.info("TLS with mutual authentication; access rules for %d certificates", len(names))
    elif config.insecure:
        log.warning("INSECURE fabric: plain TCP on %s; every host that reaches it is trusted", ", ".join(config.listen))
    session = open_session(config, "router", zconfig)
    log.info("zenoh router listening on %s", ", ".join(config.endpoints("listen")))
    heartbeat = Heartbeat(session, ctx.run_id, "router", ctx.instance,
                          info=lambda: {"listen": ",".join(config.endpoints("listen"))})
    try:
        while not ctx.stop.wait(0.5):
            pass
    finally:
        heartbeat.close()
        session.close()
    return 0
