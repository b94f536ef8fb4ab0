"""The dashboard's HTTP face (FastAPI): no Zenoh here, only a :class:`RoleTable` and run files to read.

- ``GET /api/status``: JSON, every role instance alive or gone (with its state in words), last
  seen, its counters;
- ``GET /api/history``: learning curves from ``metrics/eval.csv`` and ``metrics/learner.csv``;
- ``GET /api/episodes``: the latest evaluation's episodes (frames, chosen poses in pixels,
  outcomes), frames at ``/api/episodes/frame/<file>/<camera>/<index>.png``;
- ``GET /api/qattention``: the latest Q-attention snapshot (voxels, top-Q voxels, chosen pose);
- ``GET /healthz``: liveness of the dashboard itself;
- ``GET /metrics``: the role counters in Prometheus text format, typed, with HELP and base
  units (:mod:`dashboard.metrics`, names in :mod:`dashboard.metrics_catalog`);
- ``GET /``: the page (static/app.js, vendored uPlot and three.js: no network needed);
- ``POST /api/operator/<actor>/<action>``: a robot actor's operator buttons (:mod:`dashboard.operator_buttons`).

Who may ask is :mod:`dashboard.access`'s one middleware: the operator's commands always need the
dashboard's token, and so does every route once the dashboard binds beyond loopback.

The file-backed answers only read files the roles write anyway, are memoised on the files'
stamps and carry an ETag (a browser's revalidation gets a 304), so polling the page adds no
work to the learner or the actors. The JSON shapes are documented in docs/dashboard.md.

Counters are whatever the roles report, NaN and inf included. JSON has no spelling for
those (Starlette refuses them with an HTTP 500), so every JSON answer maps a non-finite
float to null; /metrics keeps them as Prometheus spells them (``NaN``, ``+Inf``, ``-Inf``),
since a NaN loss is worth seeing. /metrics leaves out rates (``*_per_s``) and ratios that
PromQL computes from the exported counters; /api/status keeps them for the page. /healthz is
about the dashboard only: a learner that skips non-finite updates shows it in its own counters
(``skipped_updates``, ``rejected_batches``), not as an unhealthy dashboard.
"""

from __future__ import annotations

import json
import math
import secrets
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.middleware.gzip import GZipMiddleware
from fastapi.responses import HTMLResponse, JSONResponse, PlainTextResponse, Response
from fastapi.staticfiles import StaticFiles
from prometheus_client import generate_latest

from dashboard.access import Access, TokenGuard
from dashboard.attention import AttentionSnapshot
from dashboard.episodes import EvalEpisodes
from dashboard.filecache import FileCache
from dashboard.history import RunHistory
from dashboard.metrics import CONTENT_TYPE, metrics_registry
from dashboard.registry import RoleTable
from dashboard.role_states import with_state_words

#: what the page's banner says for each ``fabric_security`` (nothing on plain loopback)
FABRIC_BANNERS = {
    "loopback": "",
    "tls": "fabric: TLS + access control",
    "insecure": "fabric: INSECURE (plain TCP beyond loopback, every host that reaches the router is trusted)",
}


def fabric_security(fabric: Any) -> str:
    """``"tls"``, ``"insecure"`` or ``"loopback"`` for a ``protocol.fabric.FabricConfig``."""
    if getattr(fabric, "certs", ""):
        return "tls"
    return "insecure" if getattr(fabric, "insecure", False) else "loopback"


def create_app(table: RoleTable, refresh_ms: int = 1000, run_dir: str | Path | None = None, *,
               token: str | None = None, host: str = "127.0.0.1", fabric: str = "loopback") -> FastAPI:
    """The app for one run; ``run_dir`` (runs/<run_id>/) feeds the charts, episodes and Q-attention view.

    ``token`` is what :mod:`dashboard.access` asks for (None: a random one nobody knows, so the
    operator's commands are refused); ``host`` the interface the server binds (beyond loopback
    every route needs the token); ``fabric`` the run's fabric security (:func:`fabric_security`).
    """
    if fabric not in FABRIC_BANNERS:
        raise ValueError(f"fabric must be one of {sorted(FABRIC_BANNERS)} (got {fabric!r})")
    app = FastAPI(title="C2F-ARM dashboard", docs_url=None, redoc_url=None, openapi_url=None)
    app.add_middleware(GZipMiddleware, minimum_size=2048)
    access = app.state.access = Access(token or secrets.token_urlsafe(32), host)
    app.add_middleware(TokenGuard, access=access)  # added last: it runs first, before any route or mount
    banner = FABRIC_BANNERS[fabric]
    page = resources.files("dashboard").joinpath("index.html").read_text(encoding="utf-8")
    page = page.replace("__FABRIC_SECURITY__", fabric).replace("__FABRIC_BANNER__", _html(banner))
    page = page.replace("__FABRIC_HIDDEN__", "" if banner else " hidden")
    page = page.replace("__REFRESH_MS__", str(int(refresh_ms))).replace("__RUN_ID__", _html(table.run_id))
    app.mount("/static", StaticFiles(directory=str(resources.files("dashboard").joinpath("static"))), name="static")
    cache, encoded = FileCache(), FileCache(max_entries=16)
    run = Path(run_dir) if run_dir is not None else None
    history = RunHistory(run, cache) if run else None
    episodes = EvalEpisodes(run, cache, history.eval_csv) if run else None
    attention = AttentionSnapshot(run, cache) if run else None

    @app.get("/api/status")
    def api_status() -> JSONResponse:
        snap = with_state_words(table.snapshot(), history.config() if history else {})
        snap.update(fabric_security=fabric, http_refused_token=access.refused)
        return JSONResponse(json_safe(snap))

    @app.get("/api/history")
    def api_history(request: Request) -> Response:
        if history is None:
            return JSONResponse({"run_id": table.run_id, "started_at": None, "replay_capacity": None,
                                 "eval": {"rows": 0, "series": {}}, "learner": {"rows": 0, "series": {}}})
        return _cached_json(request, encoded, *history.history())

    @app.get("/api/episodes")
    def api_episodes(request: Request) -> Response:
        if episodes is None:
            return JSONResponse({"available": False, "weights_version": None, "cameras": [], "episodes": [],
                                 "errors": []})
        return _cached_json(request, encoded, *episodes.episodes())

    @app.get("/api/episodes/frame/{name}/{camera}/{index:int}.png")
    def api_frame(name: str, camera: str, index: int) -> Response:
        png = episodes.frame_png(name, camera, index) if episodes else None
        if png is None:
            return PlainTextResponse("no such frame", status_code=404)
        return Response(png, media_type="image/png", headers={"Cache-Control": "max-age=86400"})

    @app.get("/api/qattention")
    def api_qattention(request: Request) -> Response:
        if attention is None:
            return JSONResponse({"available": False, "reason": "the dashboard was started without a run directory"})
        return _cached_json(request, encoded, *attention.latest())

    @app.get("/healthz")
    async def healthz() -> JSONResponse:
        snap = table.snapshot()
        body = {"ok": True, "run_id": snap["run_id"], "alive": snap["alive"], "gone": snap["gone"]}
        return JSONResponse(json_safe(body))

    registry = metrics_registry(table.snapshot)

    @app.get("/metrics")
    async def metrics() -> Response:
        return Response(generate_latest(registry), media_type=CONTENT_TYPE)

    @app.get("/")
    async def index() -> HTMLResponse:
        return HTMLResponse(page)

    from dashboard.operator_buttons import (
        router as operator_routes,  # POST /api/operator/<actor>/<action> (robot actors)
    )
    app.include_router(operator_routes)
    return app


def _cached_json(request: Request, encoded: FileCache, body: dict, etag: str) -> Response:
    """``body`` as JSON with its ETag (encoded once per ETag), or a bodiless 304 when the client holds it."""
    headers = {"ETag": etag, "Cache-Control": "no-cache"}
    if request.headers.get("if-none-match") == etag:
        return Response(status_code=304, headers=headers)
    data = encoded.get(etag, lambda: json.dumps(json_safe(body), separators=(",", ":"), allow_nan=False).encode())
    return Response(data, media_type="application/json", headers=headers)


def _html(text: str) -> str:
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (at any depth) replaced by None, so it encodes as JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value
