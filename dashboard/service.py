"""The dashboard role: a Zenoh client that watches the run and serves HTTP (uvicorn in a thread).

Its token (:mod:`dashboard.access`) is read from ``<run dir>/dashboard.token`` (made there on the
first start) or ``dashboard.token_file``; the page's URL with it is logged once serving.
"""

from __future__ import annotations

import logging
import threading
import time

import uvicorn

from dashboard.access import ensure_token, token_path
from dashboard.app import create_app, fabric_security
from dashboard.config import DashboardConfig
from dashboard.operator_buttons import OperatorPublisher
from dashboard.registry import FabricFeed, RoleTable
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext

log = logging.getLogger(__name__)


def run(config: DashboardConfig, ctx: RoleContext) -> int:
    table = RoleTable(ctx.run_id, gone_after_s=config.gone_after_s)
    token_file = token_path(ctx.run_dir, config.token_file)
    try:
        token = ensure_token(token_file)
    except (OSError, ValueError) as exc:
        log.error("no dashboard token: %s", exc)
        return 1
    app = create_app(table, refresh_ms=config.refresh_ms, run_dir=ctx.run_dir, token=token, host=config.host,
                     fabric=fabric_security(ctx.fabric))
    access = app.state.access
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
        counters=lambda: {"rejected_messages": table.rejected, "http_refused_token": access.refused},
        # never the token here: statuses are shown to readers without one (on loopback)
        info=lambda: {"url": f"http://{_url_host(config.host)}:{config.port}/"},
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
            needs = ("every route needs the token" if not access.open_reads
                     else "on loopback reads need no token, the operator's commands do")
            log.info("dashboard at http://%s:%d/?token=%s (%s; the token is in %s)", _url_host(config.host),
                     _bound_port(server) or config.port, token, needs, token_file)
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


def _url_host(host: str) -> str:
    """``host`` as it goes in a URL: an IPv6 literal in brackets."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def _bound_port(server: uvicorn.Server) -> int | None:
    """The port the server really listens on (``dashboard.port`` 0 picks one)."""
    for srv in getattr(server, "servers", []) or []:
        for sock in getattr(srv, "sockets", []) or []:
            return int(sock.getsockname()[1])
    return None
