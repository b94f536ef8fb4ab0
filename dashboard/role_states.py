"""Role states in words a person reads: running, restarting, finished, failed, gone.

The registry knows alive/gone and the last state a role reported; what it cannot see is
the launcher. A role that stopped cleanly (its last status said ``stopped``, e.g. the demo
source once its demos are in the replay) is *finished*, not gone. A role that vanished
without saying so and that the launcher restarts (``launch.restart`` in the run's
config.yaml) is *restarting* while it has been away for less than the launcher's longest
backoff plus a start-up's grace; after that it is *gone*.
"""

from __future__ import annotations

DEFAULT_RESTART_WINDOW_S = 90.0


def restart_policy(config: dict) -> tuple[set[str], float]:
    """(roles the launcher restarts, seconds a restarted role may take to reappear) from config.yaml."""
    launch = config.get("launch") if isinstance(config.get("launch"), dict) else {}
    roles = {_role_name(r) for r in launch.get("restart") or []}
    try:
        window = float(launch.get("restart_backoff_max_s", 30.0)) + float(launch.get("liveness_grace_s", 60.0))
    except (TypeError, ValueError):
        window = DEFAULT_RESTART_WINDOW_S
    return roles, window


def _role_name(role: str) -> str:
    """The launcher calls the demo source ``demo_source``; its heartbeats say ``demos``."""
    return "demos" if role == "demo_source" else str(role)


def state_word(row: dict, restartable: set[str], window_s: float) -> str:
    """The word the page shows for one row of ``RoleTable.snapshot()['roles']``."""
    reported = row.get("reported_state")
    if row.get("alive"):
        return reported or "starting"
    if reported == "stopped":
        return "finished"
    if reported == "failed":
        return "failed"
    age = row.get("last_seen_age_s")
    if row.get("role") in restartable and age is not None and age < window_s:
        return "restarting"
    return "gone"


def with_state_words(snapshot: dict, config: dict) -> dict:
    """``snapshot`` with ``state_word`` and ``restarts`` (token appearances after the first) on each role."""
    restartable, window = restart_policy(config)
    for row in snapshot.get("roles", []):
        row["state_word"] = state_word(row, restartable, window)
        row["restarts"] = max(0, int(row.get("starts", 0)) - 1)
    return snapshot
