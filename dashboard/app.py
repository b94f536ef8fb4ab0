"""The dashboard's HTTP face (FastAPI): no Zenoh here, only a :class:`RoleTable` to read.

- ``GET /api/status``: JSON, every role instance alive or gone, last seen, its counters;
- ``GET /healthz``: liveness of the dashboard itself;
- ``GET /metrics``: the same numbers in Prometheus text format;
- ``GET /``: an HTML page that polls /api/status.
"""

from __future__ import annotations

import re
from importlib import resources

from fastapi import FastAPI
from fastapi.responses import HTMLResponse, JSONResponse, PlainTextResponse

from dashboard.registry import RoleTable

_METRIC_NAME = re.compile(r"[^a-zA-Z0-9_]")


def create_app(table: RoleTable, refresh_ms: int = 1000) -> FastAPI:
    app = FastAPI(title="C2F-ARM dashboard", docs_url=None, redoc_url=None)
    page = resources.files("dashboard").joinpath("index.html").read_text(encoding="utf-8")
    page = page.replace("__REFRESH_MS__", str(int(refresh_ms))).replace("__RUN_ID__", table.run_id)

    @app.get("/api/status")
    async def api_status() -> JSONResponse:
        return JSONResponse(table.snapshot())

    @app.get("/healthz")
    async def healthz() -> JSONResponse:
        snap = table.snapshot()
        return JSONResponse({"ok": True, "run_id": snap["run_id"], "alive": snap["alive"], "gone": snap["gone"]})

    @app.get("/metrics")
    async def metrics() -> PlainTextResponse:
        return PlainTextResponse(prometheus_text(table.snapshot()), media_type="text/plain; version=0.0.4")

    @app.get("/")
    async def index() -> HTMLResponse:
        return HTMLResponse(page)

    return app


def prometheus_text(snapshot: dict) -> str:
    """Prometheus exposition format: one gauge per role counter, labelled by role/instance."""
    run = _label(snapshot["run_id"])
    lines = [
        "# HELP c2farm_role_alive 1 while a role instance is alive, 0 once gone.",
        "# TYPE c2farm_role_alive gauge",
    ]
    counters: dict[str, list[str]] = {}
    for r in snapshot["roles"]:
        labels = f'run="{run}",role="{_label(r["role"])}",instance="{_label(r["instance"])}"'
        lines.append(f"c2farm_role_alive{{{labels}}} {int(r['alive'])}")
        for name, value in sorted(r["counters"].items()):
            metric = "c2farm_" + _METRIC_NAME.sub("_", name)
            counters.setdefault(metric, []).append(f"{metric}{{{labels}}} {float(value)!r}")
    lines += [
        "# HELP c2farm_role_last_seen_age_seconds Seconds since a role instance was last heard from.",
        "# TYPE c2farm_role_last_seen_age_seconds gauge",
    ]
    for r in snapshot["roles"]:
        if r["last_seen_age_s"] is not None:
            labels = f'run="{run}",role="{_label(r["role"])}",instance="{_label(r["instance"])}"'
            lines.append(f"c2farm_role_last_seen_age_seconds{{{labels}}} {r['last_seen_age_s']!r}")
    lines += [
        "# HELP c2farm_rejected_status_messages_total Malformed status messages the dashboard rejected.",
        "# TYPE c2farm_rejected_status_messages_total counter",
        f'c2farm_rejected_status_messages_total{{run="{run}"}} {snapshot["rejected_messages"]}',
    ]
    for metric, samples in sorted(counters.items()):
        lines.append(f"# TYPE {metric} gauge")
        lines += samples
    return "\n".join(lines) + "\n"


def _label(value: str) -> str:
    return str(value).replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
