"""Every Zenoh key expression the system uses, in one place.

All keys live under ``c2farm/<run>/`` so several runs can share one router. Identifiers
are checked, because a ``/``, ``*`` or ``$`` inside one would silently widen a key.
"""

from __future__ import annotations

import re

ROOT = "c2farm"
_ID = re.compile(r"^[A-Za-z0-9_.\-]{1,128}$")


def check_id(value: str, what: str = "id") -> str:
    """Accept a run/role/instance id only if it cannot change the key's shape."""
    if not _ID.match(value):
        raise ValueError(f"invalid {what} {value!r}: use 1-128 letters, digits, '_', '.', '-'")
    return value


def episodes(run: str, actor: str = "*") -> str:
    """Actors put finished episodes here; the replay server subscribes to ``*``."""
    return f"{ROOT}/{check_id(run, 'run')}/episodes/{actor if actor == '*' else check_id(actor, 'actor')}"


def acks(run: str, actor: str = "*") -> str:
    """The replay server acknowledges each stored episode to its actor here."""
    return f"{ROOT}/{check_id(run, 'run')}/acks/{actor if actor == '*' else check_id(actor, 'actor')}"


def weights(run: str) -> str:
    """The learner publishes weight updates here and answers queries for the latest."""
    return f"{ROOT}/{check_id(run, 'run')}/weights"


def status(run: str, role: str = "*", instance: str = "*") -> str:
    """Every role's heartbeat (``Status`` messages)."""
    return f"{ROOT}/{check_id(run, 'run')}/status/{_part(role)}/{_part(instance)}"


def alive(run: str, role: str = "*", instance: str = "*") -> str:
    """Liveliness tokens: present while the role's session is up, gone when it dies."""
    return f"{ROOT}/{check_id(run, 'run')}/alive/{_part(role)}/{_part(instance)}"


def parse_role_instance(key: str) -> tuple[str, str]:
    """``c2farm/<run>/<kind>/<role>/<instance>`` -> ``(role, instance)``."""
    parts = str(key).split("/")
    if len(parts) != 5 or parts[0] != ROOT:
        raise ValueError(f"not a role key: {key!r}")
    return parts[3], parts[4]


def _part(value: str) -> str:
    return value if value in ("*", "**") else check_id(value)
