"""Configuration of the dashboard role (``c2farm dashboard``)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class DashboardConfig:
    """Where the dashboard serves and how it decides a role is gone."""

    host: str = "127.0.0.1"  #: interface to bind; 127.0.0.1 keeps it local (use 0.0.0.0 to expose it)
    port: int = 8080  #: HTTP port of the dashboard (0 picks a free one)
    gone_after_s: float = 3.0  #: a role with no status for this long counts as gone, token or not
    refresh_ms: int = 1000  #: how often the HTML page polls /api/status

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ValueError(f"port {self.port} is outside 0..65535")
        if self.gone_after_s <= 0:
            raise ValueError("gone_after_s must be > 0")
        if self.refresh_ms < 100:
            raise ValueError("refresh_ms must be >= 100")
