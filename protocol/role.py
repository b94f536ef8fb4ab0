"""What every role process is told about the run it belongs to, and how it is asked to stop.

Roles are thin shells: ``run(setup, ctx) -> int``, where ``setup`` is what the role is told
(its config section, or a small dataclass of the sections it reads, e.g. ``LearnerSetup``) and
``ctx`` this context. They never import each other; ``deploy/roles.py`` builds each setup from
the run config and the launcher and the CLI start them.
"""

from __future__ import annotations

import signal
import threading
from dataclasses import dataclass, field
from pathlib import Path

from protocol import keys
from protocol.fabric import FabricConfig


@dataclass
class RoleContext:
    """Identity and shared settings of one role process."""

    run_id: str  #: names the run; all Zenoh keys live under c2farm/<run_id>/
    instance: str  #: unique name of this process within its role, e.g. "actor-0"
    run_dir: Path  #: runs/<run_id>/: config, checkpoints, metrics, episodes
    seed: int = 0  #: base seed; each role derives its own streams from it
    fabric: FabricConfig = field(default_factory=FabricConfig)  #: how to reach the Zenoh router
    stop: threading.Event = field(default_factory=threading.Event)  #: set when the role must stop

    def __post_init__(self) -> None:
        keys.check_id(self.run_id, "run id")
        keys.check_id(self.instance, "instance")
        self.run_dir = Path(self.run_dir)


def stop_on_signals(stop: threading.Event) -> None:
    """Turn SIGTERM and SIGINT into ``stop.set()`` so a role can finish its work and exit."""

    def handler(signum, _frame) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
