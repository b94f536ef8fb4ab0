"""Who is in the run: every role instance, alive or gone, with its last counters.

:class:`RoleTable` is plain state, fed by :meth:`on_status` / :meth:`on_token` (tests feed
it directly); :class:`FabricFeed` feeds it from Zenoh: ``status/*/*`` messages and
liveliness tokens ``alive/*/*`` (with history, so tokens declared before the dashboard
started are seen too).

An instance is alive while its liveliness token is present *and* it was heard from within
``gone_after_s`` (a status or the token's arrival). A SIGKILLed process loses its token as
soon as the router sees the link drop; a hung one goes stale after ``gone_after_s``.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import zenoh

from protocol import keys
from protocol.codec import ProtocolError
from protocol.messages import Status, decode

log = logging.getLogger(__name__)

STOPPED_STATES = ("stopped", "failed")
#: Roles whose episodes feed the replay: simulated actors and robots.
ACTING_ROLES = ("actor", "robot")


@dataclass
class Instance:
    """What the dashboard knows about one role instance."""

    role: str
    instance: str
    token: Optional[bool] = None  #: liveliness token present (None: not seen either way yet)
    last_heard: float = 0.0  #: receiver's clock, last status or token arrival
    last_status: Optional[Status] = None
    starts: int = 0  #: processes seen under this name (a new pid, or host, in its status)
    #: times it went from alive to gone and came back as another process, or has not come back
    losses: int = 0
    #: times it went gone and came back as the same process: its link to the router was cut
    #: (a router restart, a network cut), not the process
    link_losses: int = 0
    _was_alive: bool = field(default=False, repr=False)
    _lost: Optional[tuple] = field(default=None, repr=False)  #: (host, pid) when it went gone, until judged


class RoleTable:
    """Thread-safe registry of role instances (Zenoh callbacks write, HTTP handlers read)."""

    def __init__(self, run_id: str = "", gone_after_s: float = 3.0, clock: Callable[[], float] = time.time):
        self.run_id = run_id
        self.gone_after_s = gone_after_s
        self.clock = clock
        self.rejected = 0  #: malformed status messages received
        self.last_error = ""
        self._lock = threading.Lock()
        self._items: dict[tuple[str, str], Instance] = {}

    def _get(self, role: str, instance: str) -> Instance:
        key = (role, instance)
        if key not in self._items:
            self._items[key] = Instance(role, instance)
        return self._items[key]

    def on_status(self, status: Status) -> None:
        with self._lock:
            item = self._get(status.role, status.instance)
            process = (status.host, status.pid)
            previous = item.last_status
            if previous is None or (previous.host, previous.pid) != process:
                item.starts += 1
            if item._lost is not None:  # back after a loss: the same process means only its link was cut
                if item._lost == process:
                    item.losses -= 1
                    item.link_losses += 1
                item._lost = None
            item.last_status = status
            item.last_heard = self.clock()
            self._refresh(item)

    def on_token(self, role: str, instance: str, present: bool) -> None:
        with self._lock:
            item = self._get(role, instance)
            item.token = present
            if present:
                item.last_heard = self.clock()
            self._refresh(item)

    def on_rejected(self, reason: str) -> None:
        with self._lock:
            self.rejected += 1
            self.last_error = reason

    def _alive(self, item: Instance, now: float) -> bool:
        if item.token is False:
            return False
        if item.last_status is not None and item.last_status.state in STOPPED_STATES and item.token is not True:
            return False
        return now - item.last_heard < self.gone_after_s

    def _refresh(self, item: Instance) -> bool:
        alive = self._alive(item, self.clock())
        if item._was_alive and not alive:
            item.losses += 1  # until it comes back as the same process (on_status)
            status = item.last_status
            item._lost = (status.host, status.pid) if status is not None else None
        item._was_alive = alive
        return alive

    def snapshot(self) -> dict:
        """JSON-able view: every instance, alive or gone, last seen, counters."""
        with self._lock:
            now = self.clock()
            roles = []
            for (role, name), item in sorted(self._items.items()):
                alive = self._refresh(item)
                status = item.last_status
                roles.append(
                    {
                        "role": role,
                        "instance": name,
                        "alive": alive,
                        "token": item.token,
                        "state": (status.state if status else "unknown") if alive else "gone",
                        "reported_state": status.state if status else None,
                        "last_seen": item.last_heard or None,
                        "last_seen_age_s": round(now - item.last_heard, 3) if item.last_heard else None,
                        "pid": status.pid if status else None,
                        "host": status.host if status else None,
                        "counters": dict(status.counters) if status else {},
                        "info": dict(status.info) if status else {},
                        "starts": item.starts,
                        "losses": item.losses,
                        "link_losses": item.link_losses,
                    }
                )
            return {
                "run_id": self.run_id,
                "time": now,
                "gone_after_s": self.gone_after_s,
                "alive": sum(r["alive"] for r in roles),
                "gone": sum(not r["alive"] for r in roles),
                "rejected_messages": self.rejected,
                "last_error": self.last_error,
                "summary": summarise(roles),
                "roles": roles,
            }


def summarise(roles: list[dict]) -> dict:
    """The few numbers a person watches during training, from the alive roles' counters.

    Env steps and episodes add up every acting role: simulated actors and robots alike.
    ``policy_lag`` is, per acting instance, how many weights versions it is behind the learner.
    The evaluation is the evaluator's, or in a run without one, a robot's own greedy episodes.
    """
    acting = [r for r in roles if r["role"] in ACTING_ROLES and r["alive"]]

    def counters(role: str) -> list[dict]:
        return [r["counters"] for r in roles if r["role"] == role and r["alive"]]

    learner = next(iter(counters("learner")), {})
    replay = next(iter(counters("replay")), {})
    evaluation = next(iter(counters("eval") + [c for c in counters("robot") if "eval_success" in c]), {})
    version = learner.get("weights_version")
    return {
        "updates": learner.get("updates"),
        "updates_per_s": learner.get("updates_per_s"),
        "env_steps": sum(r["counters"].get("env_steps", 0.0) for r in acting),
        "episodes": sum(r["counters"].get("episodes", 0.0) for r in acting),
        "replay_size": replay.get("size_transitions"),
        "samples_per_insert": replay.get("samples_per_insert"),
        "weights_version": version,
        "policy_lag": {
            r["instance"]: version - r["counters"]["weights_version"]
            for r in acting
            if version is not None and "weights_version" in r["counters"]
        },
        "eval_success": evaluation.get("eval_success"),
        "eval_episodes": evaluation.get("eval_episodes"),
        "eval_version": evaluation.get("eval_version"),
    }


class FabricFeed:
    """Subscribes to a run's status messages and liveliness tokens and feeds a :class:`RoleTable`."""

    def __init__(self, session: zenoh.Session, run_id: str, table: RoleTable):
        self.run_id, self.table = run_id, table
        self._status_sub = session.declare_subscriber(keys.status(run_id), self._on_status)
        self._alive_sub = session.liveliness().declare_subscriber(
            keys.alive(run_id), self._on_token, history=True
        )

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            role, instance = keys.parse_role_instance(str(sample.key_expr))
            status = decode(sample.payload.to_bytes(), expect=Status)
            if (status.role, status.instance, status.run_id) != (role, instance, self.run_id):
                raise ProtocolError("status", f"sent on {sample.key_expr} but names {status.role}/{status.instance}")
        except (ProtocolError, ValueError) as exc:
            self.table.on_rejected(str(exc))
            log.warning("rejected a status message on %s: %s", sample.key_expr, exc)
            return
        self.table.on_status(status)

    def _on_token(self, sample: zenoh.Sample) -> None:
        try:
            role, instance = keys.parse_role_instance(str(sample.key_expr))
        except ValueError as exc:
            self.table.on_rejected(str(exc))
            return
        self.table.on_token(role, instance, sample.kind == zenoh.SampleKind.PUT)

    def close(self) -> None:
        self._status_sub.undeclare()
        self._alive_sub.undeclare()
