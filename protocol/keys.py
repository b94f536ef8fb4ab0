"""Every Zenoh key expression the system uses, in one place.

All keys live under ``c2farm/<run>/`` so several runs can share one router. Every text
argument is checked: a ``/``, ``*``, ``$``, ``?``, ``#`` or whitespace inside an id would
silently widen or reshape a key (an ack published on ``acks/*`` reaches every actor). The
only wildcard a builder accepts is an explicit whole-chunk ``"*"`` (or ``"**"`` where
noted), meant for subscribers; a key that is put or published to should pass
:func:`concrete`.
"""

from __future__ import annotations

import re

ROOT = "c2farm"
#: Longest run/role/instance/actor id.
MAX_ID_LENGTH = 64
ANY = "*"  #: the whole-chunk wildcard, for subscribers
_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]*")
_WILDCARD_CHUNKS = ("*", "**")


def is_valid_id(value: object) -> bool:
    """True for 1-64 letters, digits, '_', '.', '-', starting with a letter or digit."""
    return isinstance(value, str) and len(value) <= MAX_ID_LENGTH and _ID.fullmatch(value) is not None


def check_id(value: str, what: str = "id") -> str:
    """Accept a run/role/instance id only if it cannot change the key's shape (or a path:
    ids also name run directories, so ``..`` is refused too). Raises ValueError."""
    if not is_valid_id(value):
        shown = repr(value[:80]) if isinstance(value, str) else type(value).__name__
        raise ValueError(
            f"invalid {what} {shown}: use 1-{MAX_ID_LENGTH} letters, digits, '_', '.', '-', "
            "starting with a letter or digit"
        )
    return value


def episodes(run: str, actor: str = ANY) -> str:
    """Actors put finished episodes here; the replay server subscribes to ``*``."""
    return f"{_root(run)}/episodes/{_part(actor, 'actor', ('*',))}"


def acks(run: str, actor: str = ANY) -> str:
    """The replay server acknowledges each stored episode to its actor here."""
    return f"{_root(run)}/acks/{_part(actor, 'actor', ('*',))}"


def weights(run: str) -> str:
    """The learner publishes weight updates here and answers queries for the latest."""
    return f"{_root(run)}/weights"


def status(run: str, role: str = ANY, instance: str = ANY) -> str:
    """Every role's heartbeat (``Status`` messages)."""
    return f"{_root(run)}/status/{_part(role, 'role')}/{_part(instance, 'instance')}"


def alive(run: str, role: str = ANY, instance: str = ANY) -> str:
    """Liveliness tokens: present while the role's session is up, gone when it dies."""
    return f"{_root(run)}/alive/{_part(role, 'role')}/{_part(instance, 'instance')}"


def operator(run: str, actor: str = ANY) -> str:
    """A person's commands (``OperatorCommand``) to one robot actor; the robot actor subscribes to its own."""
    return f"{_root(run)}/operator/{_part(actor, 'actor', ('*',))}"


def concrete(key: str) -> str:
    """``key`` itself if it names exactly one resource (no wildcard chunk), else ValueError.

    Wrap every key that is put or published to, so a wildcard can never be a destination.
    """
    if not isinstance(key, str) or any(c in key for c in "*$?#") or any(c.isspace() for c in key):
        raise ValueError(f"not a concrete key: {key!r}")
    return key


def parse_role_instance(key: str) -> tuple[str, str]:
    """``c2farm/<run>/<kind>/<role>/<instance>`` -> ``(role, instance)``, both valid ids."""
    parts = str(key).split("/")
    if len(parts) != 5 or parts[0] != ROOT or not all(is_valid_id(p) for p in parts[1:]):
        raise ValueError(f"not a role key: {str(key)[:200]!r}")
    return parts[3], parts[4]


def _root(run: str) -> str:
    return f"{ROOT}/{check_id(run, 'run')}"


def _part(value: str, what: str, wildcards: tuple[str, ...] = _WILDCARD_CHUNKS) -> str:
    return value if isinstance(value, str) and value in wildcards else check_id(value, what)
