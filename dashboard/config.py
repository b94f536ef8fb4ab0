"""Configuration of the dashboard role (``c2farm dashboard``)."""

from __future__ import annotations

from dataclasses import dataclass

from protocol.config_checks import above, at_least, non_empty, within


@dataclass
class DashboardConfig:
    """Where the dashboard serves and how it decides a role is gone."""

    host: str = "127.0.0.1"  #: interface to bind; 127.0.0.1 keeps it local (0.0.0.0 exposes it, token required)
    port: int = 8080  #: HTTP port of the dashboard, 0..65535 (0 picks a free one)
    gone_after_s: float = 3.0  #: a role with no status for this long (seconds, > 0) counts as gone, token or not
    refresh_ms: int = 1000  #: how often the HTML page polls /api/status, milliseconds, >= 100
    token_file: str = ""  #: file holding the page's token (made 0600 if missing); empty: <run dir>/dashboard.token

    def __post_init__(self) -> None:
        non_empty(self, "host")
        within(self, 0, 65535, "port")
        above(self, 0, "gone_after_s")
        at_least(self, 100, "refresh_ms")
