"""The dashboard's HTTP face (FastAPI): no Zenoh here, only a :class:`RoleTable` to read.

- ``GET /api/status``: JSON, every role instance alive or gone, last seen, its counters;
- ``GET /healthz``: liveness of the dashboard itself;
- ``GET /metrics``: the same numbers in Prometheus text format;
- ``GET /``: an HTML page that polls /api/status.

Counters are whatever the roles report, NaN and inf included. JSON has no spelling for
those (Starlette refuses them with an HTTP 500), so every JSON answer maps a non-finite
float to null; /metrics keeps them as Prometheus spells them (``NaN``, ``+Inf``, ``-Inf``),
since a NaN loss is worth seeing. /healthz is about the dashboard only: a learner that
skips non-finite updates shows it in its own counters (``skipped_updates``,
``rejected_batches``), not as an unhealthy dashboard.
"""

from __future__ import annotations

import math
import re
from importlib import resources
from typing import Any

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
        return JSONResponse(json_safe(table.snapshot()))

    @app.get("/healthz")
    async def healthz() -> JSONResponse:
        snap = table.snapshot()
        body = {"ok": True, "run_id": snap["run_id"], "alive": snap["alive"], "gone": snap["gone"]}
        return JSONResponse(json_safe(body))

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
            counters.setdefault(metric, []).append(f"{metric}{{{labels}}} {_number(value)}")
    lines += [
        "# HELP c2farm_role_last_seen_age_seconds Seconds since a role instance was last heard from.",
        "# TYPE c2farm_role_last_seen_age_seconds gauge",
    ]
    for r in snapshot["roles"]:
        if r["last_seen_age_s"] is not None:
            labels = f'run="{run}",role="{_label(r["role"])}",instance="{_label(r["instance"])}"'
            lines.append(f"c2farm_role_last_seen_age_seconds{{{labels}}} {_number(r['last_seen_age_s'])}")
    lines += [
        "# HELP c2farm_rejected_status_messages_total Malformed status messages the dashboard rejected.",
        "# TYPE c2farm_rejected_status_messages_total counter",
        f'c2farm_rejected_status_messages_total{{run="{run}"}} {snapshot["rejected_messages"]}',
    ]
    for metric, samples in sorted(counters.items()):
        lines.append(f"# TYPE {metric} gauge")
        lines += samples
    return "\n".join(lines) + "\n"


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (at any depth) replaced by None, so it encodes as JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def _number(value) -> str:
    """A sample value as Prometheus writes it (``NaN``, ``+Inf``, ``-Inf`` for the non-finite)."""
    value = float(value)
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    return repr(value)


def _label(value: str) -> str:
    return str(value).replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
