"""Endpoints as the launcher and the role CLI both need them: parse, probe (the router, the dashboard), pick a port.

Shared by ``deploy/cli.py`` and ``deploy/launch.py`` so neither imports the other.
"""

from __future__ import annotations

import socket
import threading
import time
from typing import Sequence


def tcp_endpoints(endpoints: Sequence[str]) -> list[tuple[str, int]]:
    """``tcp/HOST:PORT`` endpoints as (host, port); other protocols are skipped."""
    out = []
    for endpoint in endpoints:
        proto, _, address = endpoint.partition("/")
        address = address.split("#", 1)[0].split("?", 1)[0]
        if proto != "tcp" or ":" not in address:
            continue
        host, _, port = address.rpartition(":")
        try:
            out.append((host.strip("[]"), int(port)))
        except ValueError:
            continue
    return out


def wait_for_listener(endpoints: Sequence[str], timeout_s: float, stop: threading.Event) -> bool:
    """Poll until one of ``endpoints`` (the router's, the dashboard's) accepts a TCP connection (True) or time is up."""
    targets = tcp_endpoints(endpoints)
    if not targets:
        return True
    deadline = time.monotonic() + timeout_s
    while True:
        for host, port in targets:
            try:
                with socket.create_connection((host, port), timeout=1.0):
                    return True
            except OSError:
                pass
        if time.monotonic() >= deadline or stop.wait(0.1):
            return False


def loopback(endpoint: str) -> str:
    """A wildcard listen endpoint (``0.0.0.0``, ``[::]``) as the address a local client dials."""
    for wildcard in ("0.0.0.0", "[::]"):
        endpoint = endpoint.replace(f"/{wildcard}:", "/127.0.0.1:")
    return endpoint


def free_port() -> int:
    """A TCP port that was free a moment ago on 127.0.0.1."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]
