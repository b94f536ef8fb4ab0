"""The Zenoh session every role opens: an embedded router on one host, clients elsewhere.

No separate ``zenohd`` binary is needed: the launcher (or any one process) opens a session
in router mode listening on ``tcp/127.0.0.1:7447``; every role connects to it as a client
with multicast scouting off, so nothing leaks onto the LAN. Across machines the same flags
point at a router on the hub host (``--listen tcp/0.0.0.0:7447`` there, ``--connect
tcp/HUB:7447`` elsewhere).

Beyond loopback the fabric is TLS with mutual authentication, or nothing: with ``certs`` (a
directory made by ``c2farm certs``) every ``tcp/`` endpoint becomes ``tls/``, each process
presents the certificate of its ``identity`` (``role.instance``) and trusts only the run's
authority, and the router judges every message by that name (``deploy/access_control.py``).
An address beyond loopback without ``certs`` is refused unless ``insecure`` says otherwise.
Every role is a ``client`` of the router (peer links would bypass its access control), and a
client checks that it really holds a router link once open.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from protocol.config_checks import at_least, endpoint_host, is_loopback_host, zenoh_endpoints

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
    #: directory made by `c2farm certs`: TLS with mutual authentication on every link and access control at the
    #: router; empty = plain TCP, which stays on loopback unless ``insecure``
    certs: str = ""
    #: allow plain TCP beyond loopback: anyone who reaches the router is trusted (the dashboard and the launcher's
    #: progress line say so)
    insecure: bool = False
    #: the certificate this process presents, ``role.instance``; the CLI sets it for each role it starts
    identity: str = ""

    def __post_init__(self) -> None:
        zenoh_endpoints(self, "connect", listen=False)
        zenoh_endpoints(self, "listen", listen=True)
        at_least(self, 100, "reconnect_max_ms")
        if not self.certs and not self.insecure:
            for name in ("listen", "connect"):
                for endpoint in getattr(self, name):
                    host = endpoint_host(endpoint)
                    if host is not None and not is_loopback_host(host):
                        raise ValueError(f"{name} {endpoint} is beyond loopback: pass --certs DIR (made by "
                                         "`c2farm certs`) for TLS, or --insecure to trust every host that reaches it")

    @property
    def secure(self) -> bool:
        """Whether links are TLS with mutual authentication."""
        return bool(self.certs)

    def endpoints(self, name: str) -> list[str]:
        """``listen`` or ``connect`` as dialled: ``tcp/`` becomes ``tls/`` when the fabric is secure."""
        endpoints = list(getattr(self, name))
        return [("tls/" + e[4:]) if self.secure and e.startswith("tcp/") else e for e in endpoints]

    def certificate(self) -> tuple[Path, Path, Path]:
        """(authority, certificate, private key) files of ``identity``."""
        if not self.identity:
            raise ValueError("fabric.identity: not set, so no certificate can be chosen (the CLI sets it per role)")
        base = Path(self.certs)
        return base / "ca.pem", base / "zenoh" / f"{self.identity}.pem", base / "zenoh" / f"{self.identity}.key"


def zenoh_config(fabric: FabricConfig, mode: str = "client") -> zenoh.Config:
    """Build the Zenoh config for ``mode`` "client" (every role) or "router" (the hub)."""
    if mode not in ("client", "router", "peer"):
        raise ValueError(f"unknown zenoh mode {mode!r}")
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    if mode == "router":
        config.insert_json5("listen/endpoints", json.dumps(fabric.endpoints("listen")))
    else:
        config.insert_json5("connect/endpoints", json.dumps(fabric.endpoints("connect")))
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
    if fabric.secure:
        ca, cert, key = fabric.certificate()
        side = "listen" if mode == "router" else "connect"
        config.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": str(ca),
            f"{side}_certificate": str(cert),
            f"{side}_private_key": str(key),
            "enable_mtls": True,
            "close_link_on_expiration": True,
        }))
    return config


def open_session(fabric: FabricConfig, mode: str = "client", config: zenoh.Config | None = None) -> zenoh.Session:
    """Open a session (``config``: one built by :func:`zenoh_config` and extended, e.g. with access rules).

    A client fails fast, with a clear message, if no router answers or the TLS handshake is
    refused, and checks it holds a router link: a session that opened without one would
    otherwise wait silently forever.
    """
    where = fabric.endpoints("listen" if mode == "router" else "connect")
    try:
        session = zenoh.open(config if config is not None else zenoh_config(fabric, mode))
    except zenoh.ZError as exc:
        hint = f" (TLS as {fabric.identity}: is the router's certificate from the same `c2farm certs`?)" \
            if fabric.secure else ""
        raise ConnectionError(f"cannot open a zenoh {mode} session on {where}: {exc}{hint}") from None
    if mode == "client" and not list(session.info.routers_zid()):
        session.close()
        raise ConnectionError(f"zenoh client session on {where} opened without a router link")
    return session
