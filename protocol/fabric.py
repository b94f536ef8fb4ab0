"""The Zenoh session every role opens: an embedded router on one host, clients elsewhere.

No separate ``zenohd`` binary is needed: the launcher (or any one process) opens a session
in router mode listening on ``tcp/127.0.0.1:7447``; every role connects to it as a client
with multicast scouting off, so nothing leaks onto the LAN. Across machines the same flags
point at a router on the hub host (``--listen tcp/0.0.0.0:7447`` there, ``--connect
tcp/HUB:7447`` elsewhere).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import zenoh

from protocol.config_checks import at_least, zenoh_endpoints

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


@dataclass
class FabricConfig:
    """How a process joins the Zenoh fabric."""

    #: router endpoints clients dial, at least one (tcp/HOST:PORT, port 1-65535)
    connect: list[str] = field(default_factory=lambda: [DEFAULT_ENDPOINT])
    #: endpoints the router listens on, at least one (tcp/HOST:PORT, port 0-65535)
    listen: list[str] = field(default_factory=lambda: [DEFAULT_ENDPOINT])
    shared_memory: bool = True  #: Zenoh's same-host shared-memory transport (off measures the TCP path)
    #: a client that lost its router redials at least this often, >= 100 (a restarted router is rejoined within about
    #: this)
    reconnect_max_ms: int = 1000

    def __post_init__(self) -> None:
        zenoh_endpoints(self, "connect", listen=False)
        zenoh_endpoints(self, "listen", listen=True)
        at_least(self, 100, "reconnect_max_ms")


def zenoh_config(fabric: FabricConfig, mode: str = "client") -> zenoh.Config:
    """Build the Zenoh config for ``mode`` "client" (every role) or "router" (the hub)."""
    if mode not in ("client", "router", "peer"):
        raise ValueError(f"unknown zenoh mode {mode!r}")
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    if mode == "router":
        config.insert_json5("listen/endpoints", json.dumps(list(fabric.listen)))
    else:
        config.insert_json5("connect/endpoints", json.dumps(list(fabric.connect)))
        # Opening still fails fast without a router (the defaults); once connected, a client
        # that loses its router (killed, restarted) redials forever, and Zenoh re-declares its
        # subscribers, queryables and liveliness tokens on the new link. Zenoh's default
        # backoff grows to 4 s; this caps it so a restarted router is rejoined within ~1 s.
        period = max(100, int(fabric.reconnect_max_ms))
        config.insert_json5(
            "connect/retry",
            json.dumps({"period_init_ms": min(250, period), "period_max_ms": period, "period_increase_factor": 2}),
        )
    config.insert_json5("transport/shared_memory/enabled", json.dumps(bool(fabric.shared_memory)))
    return config


def open_session(fabric: FabricConfig, mode: str = "client") -> zenoh.Session:
    """Open a session; a client fails fast with a clear message if no router answers."""
    try:
        return zenoh.open(zenoh_config(fabric, mode))
    except zenoh.ZError as exc:
        where = fabric.listen if mode == "router" else fabric.connect
        raise ConnectionError(f"cannot open a zenoh {mode} session on {where}: {exc}") from None
