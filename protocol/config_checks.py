"""Range checks for the config dataclasses: one call per rule, in each section's ``__post_init__``.

Every check raises ``ValueError("<field> must be <rule> (got <value>)")``. The message starts
with the field's name, so ``deploy/config_loader.py`` reports it as one line naming the dotted
path (``learner.batch_size must be >= 1 (got -3)``) when a config is resolved, before anything
starts. ``None`` (an Optional field left unset) passes every check; a float that is not finite
fails every range check. Standard library only: every role's config imports it.
"""

from __future__ import annotations

import math
import re
from typing import Any, Iterable

#: Zenoh link protocols whose address is HOST:PORT.
_HOST_PORT_LINKS = ("tcp", "udp", "tls", "quic", "ws")


def at_least(cfg: Any, low: float, *names: str) -> None:
    """Each named field (or each item of a tuple field) is ``>= low``."""
    for name in names:
        _range(name, getattr(cfg, name), low, None, False, False, _is_int(cfg, name))


def above(cfg: Any, low: float, *names: str) -> None:
    """Each named field (or each item of a tuple field) is ``> low``."""
    for name in names:
        _range(name, getattr(cfg, name), low, None, True, False, _is_int(cfg, name))


def within(cfg: Any, low: float, high: float, *names: str, open_low: bool = False, open_high: bool = False) -> None:
    """Each named field (or each item of a tuple field) is in ``[low, high]`` (ends open as asked)."""
    for name in names:
        _range(name, getattr(cfg, name), low, high, open_low, open_high, _is_int(cfg, name))


def finite(cfg: Any, *names: str) -> None:
    """Each named float field (or each item of a tuple field) is a finite number."""
    for name in names:
        for where, value in _items(name, getattr(cfg, name)):
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"{where} must be a finite number (got {_show(value)})")


def non_empty(cfg: Any, *names: str) -> None:
    """Each named string (blank counts as empty) or list field has something in it."""
    for name in names:
        value = getattr(cfg, name)
        if value is not None and not (value.strip() if isinstance(value, str) else len(value)):
            raise ValueError(f"{name} must not be empty (got {_show(value)})")


def one_of(cfg: Any, name: str, choices: Iterable[Any]) -> None:
    """The named field is one of ``choices``."""
    value, choices = getattr(cfg, name), tuple(choices)
    if value is not None and value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, choices))} (got {_show(value)})")


def distinct(cfg: Any, name: str) -> None:
    """The named list/tuple field names nothing twice."""
    value = list(getattr(cfg, name) or ())
    repeated = sorted({str(v) for v in value if value.count(v) > 1})
    if repeated:
        raise ValueError(f"{name} must not repeat an entry (got {', '.join(repeated)} twice)")


def zmq_endpoint(cfg: Any, name: str, allow_empty: bool = False) -> None:
    """A ZeroMQ endpoint: ``tcp://HOST:PORT`` (port 1-65535), ``ipc://PATH`` or ``inproc://NAME``."""
    value = getattr(cfg, name)
    if allow_empty and value == "":
        return
    transport, sep, address = str(value).partition("://")
    if sep and address and transport in ("ipc", "inproc"):
        return
    host, _, port = address.rpartition(":")
    if transport == "tcp" and host and port.isdigit() and 1 <= int(port) <= 65535:
        return
    empty = " or empty" if allow_empty else ""
    raise ValueError(f"{name} must be tcp://HOST:PORT (port 1-65535), ipc://PATH or inproc://NAME{empty} "
                     f"(got {_show(value)})")


def zenoh_endpoints(cfg: Any, name: str, listen: bool) -> None:
    """A non-empty list of Zenoh endpoints ``PROTO/ADDRESS``; ``tcp/HOST:PORT`` with port 1-65535
    (0-65535 where the router listens: 0 picks a free port)."""
    value = getattr(cfg, name)
    if not value:
        raise ValueError(f"{name} must name at least one endpoint, e.g. tcp/127.0.0.1:7447 (got {_show(value)})")
    low = 0 if listen else 1
    for i, endpoint in enumerate(value):
        proto, _, address = str(endpoint).partition("/")
        address = address.split("#", 1)[0].split("?", 1)[0]
        if not re.fullmatch(r"[a-z][a-z0-9-]*", proto) or not address:
            raise ValueError(f"{name}[{i}] must be PROTO/ADDRESS, e.g. tcp/127.0.0.1:7447 (got {_show(endpoint)})")
        if proto in _HOST_PORT_LINKS:
            host, _, port = address.rpartition(":")
            if not host or not port.isdigit() or not low <= int(port) <= 65535:
                raise ValueError(f"{name}[{i}] must be {proto}/HOST:PORT with port {low}-65535 (got {_show(endpoint)})")


# -- the one range rule ---------------------------------------------------------------------


def _range(name: str, value: Any, low, high, open_low: bool, open_high: bool, integer: bool) -> None:
    for where, v in _items(name, value):
        if v is None:
            continue
        ok = (v > low if open_low else v >= low) if low is not None else True
        if high is not None:
            ok = ok and (v < high if open_high else v <= high)
        is_finite = not isinstance(v, float) or math.isfinite(v)
        if not (ok and is_finite):
            rule = _rule(low, high, open_low, open_high, integer)
            finite = "finite and " if high is None and not is_finite else ""  # [0, 1] already says finite
            raise ValueError(f"{where} must be {finite}{rule} (got {_show(v)})")


def _rule(low, high, open_low: bool, open_high: bool, integer: bool) -> str:
    if high is None:
        return f"{'>' if open_low else '>='} {_num(low)}"
    if integer and not (open_low or open_high):
        return f"in {low}..{high}"
    return f"in {'(' if open_low else '['}{_num(low)}, {_num(high)}{')' if open_high else ']'}"


def _is_int(cfg: Any, name: str) -> bool:
    """Whether the field is declared an int (its range reads ``1..64``; a float's ``[0, 1]``)."""
    field = getattr(type(cfg), "__dataclass_fields__", {}).get(name)
    declared = str(field.type) if field is not None else type(getattr(cfg, name)).__name__
    return "int" in declared and "float" not in declared


def _items(name: str, value: Any) -> list[tuple[str, Any]]:
    """``[(name, value)]``, or one ``(name[i], item)`` per item of a tuple or list."""
    if isinstance(value, (tuple, list)):
        return [(f"{name}[{i}]", v) for i, v in enumerate(value)]
    return [(name, value)]


def _num(x) -> str:
    return str(int(x)) if isinstance(x, float) and x.is_integer() else str(x)


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def is_loopback_host(host: str) -> bool:
    """Whether ``host`` (an IP literal or a name, brackets allowed) stays on this machine."""
    import ipaddress

    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def endpoint_host(endpoint: str) -> str | None:
    """The host of a ``PROTO/HOST:PORT`` Zenoh endpoint or a ``tcp://HOST:PORT`` ZeroMQ one (None: no host)."""
    text = str(endpoint).split("#", 1)[0].split("?", 1)[0]
    _, sep, address = text.partition("://") if "://" in text else text.partition("/")
    if not sep or ":" not in address:
        return None
    return address.rpartition(":")[0]
