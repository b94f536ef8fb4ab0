"""Who may use the dashboard: its token, and the one middleware that checks it on every request.

The token is a random string kept in ``<run dir>/dashboard.token`` (mode 0600; made on first
start, kept across restarts so an open page keeps working; ``dashboard.token_file`` points
elsewhere). A request shows it as ``Authorization: Bearer <token>`` or ``?token=<token>``; the
page takes it from its own URL, keeps it in sessionStorage and sends the header on every fetch.

What needs it (:meth:`Access.needs_token`):

- bound to loopback (127.0.0.0/8, ::1, localhost), reads (``GET``, ``HEAD``) stay open, as
  they were: only processes on this machine reach them;
- bound beyond loopback, every route does: the page, the JSON API, ``/static``, ``/metrics``;
- every other method does, always: the operator's robot commands
  (``POST /api/operator/<actor>/<action>``, :mod:`dashboard.operator_buttons`) move an arm.

What a browser loads by itself (``<script>``, ``<img>``, the page's module imports) cannot
carry a header, so a page opened with a good ``?token=`` also gets it back as an ``HttpOnly``,
``SameSite=Strict`` cookie named for the port, and that cookie counts for reads only: a
command still needs the header (or ``?token=``), which another site's form cannot send.
A refused request gets a 401 with a JSON ``error``; refusals are counted (``refused``, shown as
``http_refused_token``) and logged at most once per :data:`LOG_EVERY_S`.
"""

from __future__ import annotations

import hmac
import logging
import os
import re
import secrets
import threading
import time
from pathlib import Path
from urllib.parse import parse_qsl

from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from protocol.config_checks import is_loopback_host

log = logging.getLogger(__name__)

TOKEN_FILE = "dashboard.token"  #: the token's file name in the run directory (the launcher reads it too)
TOKEN_RE = re.compile(r"[A-Za-z0-9_.~-]{16,512}")  #: what a token file may hold (secrets.token_urlsafe writes 43)
READS = frozenset({"GET", "HEAD"})
LOG_EVERY_S = 10.0


def token_path(run_dir: str | Path, token_file: str = "") -> Path:
    """Where the dashboard's token lives: ``token_file`` if set, else ``<run_dir>/dashboard.token``."""
    return Path(token_file) if token_file else Path(run_dir) / TOKEN_FILE


def ensure_token(path: str | Path) -> str:
    """The token in ``path``; a fresh one written there first (mode 0600, appearing whole) when it is missing."""
    path = Path(path)
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            with os.fdopen(fd, "w", encoding="ascii") as f:
                f.write(secrets.token_urlsafe(32) + "\n")
                f.flush()
                os.fsync(f.fileno())
            try:
                os.link(tmp, path)  # never replaces a token another process wrote meanwhile
            except FileExistsError:
                pass
        finally:
            tmp.unlink(missing_ok=True)
    mode = path.stat().st_mode & 0o777
    if mode & 0o077:
        log.warning("%s was readable by others (mode %o): made it 0600", path, mode)
        os.chmod(path, 0o600)
    token = path.read_text(encoding="utf-8").strip()
    if not TOKEN_RE.fullmatch(token):
        raise ValueError(f"{path}: not a dashboard token (16 or more of A-Z a-z 0-9 - _ . ~ expected); delete it "
                         "for a fresh one")
    return token


class Access:
    """Which requests need the token, given the interface the dashboard binds; counts what it refused."""

    def __init__(self, token: str, host: str = "127.0.0.1") -> None:
        self.token = token
        self.host = host  #: the interface the server binds
        self.open_reads = is_loopback_host(host)  #: reads need no token: only while bound to loopback
        self.refused = 0  #: requests refused for a missing or wrong token
        self._lock = threading.Lock()
        self._logged_at = -LOG_EVERY_S
        self._unlogged = 0

    def needs_token(self, method: str) -> bool:
        return method.upper() not in READS or not self.open_reads

    def accepts(self, presented: str | None) -> bool:
        return presented is not None and hmac.compare_digest(presented.encode("utf-8"), self.token.encode("utf-8"))

    def refuse(self, method: str, path: str, client: str, wrong: bool) -> None:
        """Count one refused request; log the refusals at most once per :data:`LOG_EVERY_S`."""
        with self._lock:
            self.refused += 1
            self._unlogged += 1
            now = time.monotonic()
            if now - self._logged_at < LOG_EVERY_S:
                return
            count, self._unlogged, self._logged_at = self._unlogged, 0, now
        log.warning("refused %d request(s) without the dashboard's token since the last such line (one per %.0f s at "
                    "most); latest: %s %s from %s (%s)", count, LOG_EVERY_S, method, path[:120], client,
                    "wrong token" if wrong else "no token")


class TokenGuard:
    """ASGI middleware: lets a request through when :class:`Access` says it may, else answers 401."""

    def __init__(self, app: ASGIApp, access: Access) -> None:
        self.app, self.access = app, access

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        access = self.access
        method = scope.get("method", "GET")
        headers = _headers(scope)
        queried = _query_token(scope)
        explicit = _bearer(headers.get("authorization")) or queried
        if access.accepts(explicit):
            if explicit == queried and method in READS and scope["path"] == "/" and scope["type"] == "http":
                send = self._with_cookie(scope, send)  # the page's own <script>s and <img>s carry no header
            await self.app(scope, receive, send)
            return
        if not access.needs_token(method) or (
                explicit is None and method in READS
                and access.accepts(_cookies(headers.get("cookie")).get(cookie_name(scope)))):
            await self.app(scope, receive, send)
            return
        wrong = explicit is not None
        access.refuse(method, scope["path"], str((scope.get("client") or ("?",))[0]), wrong)
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})
            return
        response = JSONResponse(
            {"error": "wrong token" if wrong else "token required",
             "detail": "this dashboard needs its token (the run directory's dashboard.token): open the page as "
                       "/?token=<token>, or send Authorization: Bearer <token>"},
            status_code=401, headers={"WWW-Authenticate": 'Bearer realm="c2farm dashboard"'})
        await response(scope, receive, send)

    def _with_cookie(self, scope: Scope, send: Send) -> Send:
        cookie = f"{cookie_name(scope)}={self.access.token}; Path=/; HttpOnly; SameSite=Strict"

        async def sending(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []), (b"set-cookie", cookie.encode())]}
            await send(message)

        return sending


def cookie_name(scope: Scope) -> str:
    """One cookie per port: browsers share cookies across the ports of a host, dashboards do not share tokens."""
    server = scope.get("server") or ("", 0)
    return f"c2farm_dashboard_{server[1] or 0}"


def _headers(scope: Scope) -> dict[str, str]:
    return {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}


def _bearer(value: str | None) -> str | None:
    if not value:
        return None
    scheme, _, token = value.strip().partition(" ")
    return token.strip() if scheme.lower() == "bearer" and token.strip() else None


def _query_token(scope: Scope) -> str | None:
    query = scope.get("query_string", b"").decode("latin-1")
    return next((v for k, v in parse_qsl(query, keep_blank_values=True) if k == "token"), None)


def _cookies(value: str | None) -> dict[str, str]:
    out: dict[str, str] = {}
    for part in (value or "").split(";"):
        name, sep, content = part.strip().partition("=")
        if sep:
            out.setdefault(name, content)
    return out
