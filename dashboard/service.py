"""The dashboard role: a Zenoh client that watches the run and serves HTTP (uvicorn in a thread)."""

from __future__ import annotations

import logging
import threading
import time

import uvicorn

from dashboard.app import create_app
from dashboard.config import DashboardConfig
from dashboard.operator_buttons import OperatorPublisher
from dashboard.registry import FabricFeed, RoleTable
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext

log = logging.getLogger(__name__)


def run(config: DashboardConfig, ctx: RoleContext) -> int:
    table = RoleTable(ctx.run_id, gone_after_s=config.gone_after_s)
    app = create_app(table, refresh_ms=config.refresh_ms, run_dir=ctx.run_dir)
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=config.host,
            port=config.port,
            log_level="warning",
            lifespan="off",
        )
    )
    session = open_session(ctx.fabric)
    # the robot actors' buttons (dashboard/operator_buttons.py)
    app.state.operator = OperatorPublisher(session, ctx.run_id)
    feed = FabricFeed(session, ctx.run_id, table)
    heartbeat = Heartbeat(
        session,
        ctx.run_id,
        "dashboard",
        ctx.instance,
        counters=lambda: {"rejected_messages": table.rejected},
        info=lambda: {"url": f"http://{config.host}:{config.port}/"},
    )
    thread = threading.Thread(target=server.run, name="uvicorn", daemon=True)
    thread.start()
    code = 0
    try:
        while not server.started:
            if not thread.is_alive() or ctx.stop.is_set():
                if not ctx.stop.is_set():
                    log.error("cannot serve on %s:%d (port in use?)", config.host, config.port)
                    code = 1
                break
            time.sleep(0.02)
        else:
            log.info("dashboard at http://%s:%d/", config.host, config.port)
            while not ctx.stop.wait(0.5):
                if not thread.is_alive():
                    log.error("the HTTP server stopped unexpectedly")
                    code = 1
                    break
    finally:
        server.should_exit = True
        thread.join(timeout=5)
        heartbeat.close()
        feed.close()
        session.close()
    return code
