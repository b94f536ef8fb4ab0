"""The one typed config of a run: a section per concern, loaded from YAML, overridable, saved.

Resolution order (later wins): dataclass defaults -> preset (``configs/<name>.yaml``) ->
``--config FILE`` -> first-class CLI flags (``--actors``, ``--connect`` ...) -> ``--set a.b=v``.
The resolved config is written to ``runs/<run-id>/config.yaml``; every role process the
launcher starts reads that same file, so all of them agree.

Adding a section is one line in :class:`RunConfig` (its dataclass lives with its role).
"""

from __future__ import annotations

import dataclasses
import json
import platform
import subprocess
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any, Optional

import yaml

from dashboard.config import DashboardConfig
from deploy.config_loader import ConfigError, field_docs, from_dict, load_yaml, merge, to_dict
from protocol import keys
from protocol.fabric import FabricConfig
from actors.config import ActorConfig
from actors.robot.config import RobotConfig
from actors.sim.config import SimConfig
from learner.config import LearnerConfig
from qattention.config import QAttentionConfig
from replay_server.config import ReplayConfig

REPO_ROOT = Path(__file__).resolve().parent.parent
PRESET_DIRS = (Path.cwd() / "configs", REPO_ROOT / "configs")
DEFAULT_PRESET = "cpu-small"
#: Every role, in the order the launcher starts them.
ROLES = ("router", "replay", "dashboard", "learner", "demo_source", "actor", "eval", "robot")
#: Roles `c2farm launch` starts unless told otherwise (a robot actor only with --robot).
DEFAULT_ROLES = tuple(r for r in ROLES if r != "robot")
#: Roles that finish their job and exit; restarted only when they fail.
ONE_SHOT_ROLES = ("demo_source",)
#: role -> the instance name a role process gets unless told otherwise.
DEFAULT_INSTANCE = {
    "router": "router",
    "replay": "replay",
    "learner": "learner",
    "actor": "actor-0",
    "eval": "eval",
    "demo_source": "demos",
    "dashboard": "dashboard",
    "robot": "robot-0",
}


@dataclass
class RunSection:
    """Identity of the run and where its files go."""

    run_id: Optional[str] = None  #: names the run and its Zenoh keys; None: `launch` picks a timestamp
    seed: int = 0  #: base random seed; every role derives its own streams from it
    runs_dir: str = "runs"  #: parent folder of run directories (runs/<run-id>/)

    def __post_init__(self) -> None:
        if self.run_id is not None:
            keys.check_id(self.run_id, "run id")


@dataclass
class LaunchConfig:
    """What `c2farm launch` starts on this machine and how it supervises it."""

    roles: list[str] = field(default_factory=lambda: list(DEFAULT_ROLES))  #: roles started here (others run elsewhere); add robot for a robot actor
    num_actors: int = 2  #: actor processes to start
    instance_prefix: str = ""  #: prepended to the instance names started here, e.g. "box3-" (unique per machine)
    restart: list[str] = field(  #: roles restarted when their process dies or goes silent (one-shot roles only on failure)
        default_factory=lambda: list(ROLES)
    )
    progress_every_s: float = 30.0  #: print a progress line (updates, env steps, eval success) this often; 0 = never
    restart_backoff_s: float = 1.0  #: wait before restarting an instance; doubles per quick failure in a row
    restart_backoff_max_s: float = 30.0  #: ceiling of the restart wait; an instance that ran this long starts the doubling afresh
    max_restarts: int = 20  #: restarts per instance before the launcher gives up on it
    liveness_timeout_s: float = 15.0  #: a role whose beacon (runs/<id>/heartbeats/) is silent this long is killed and restarted; 0 = never
    liveness_grace_s: float = 60.0  #: a just-started role is not judged silent for this long (slow imports on a busy machine)
    shutdown_grace_s: float = 8.0  #: one deadline for the whole stop: SIGTERM all, SIGKILL what is left after it (stop < 10 s)
    router_wait_s: float = 20.0  #: how long roles wait for the Zenoh router to accept connections

    def __post_init__(self) -> None:
        for role in list(self.roles) + list(self.restart):
            if role not in ROLES:
                raise ValueError(f"unknown role {role!r}; roles are {', '.join(ROLES)}")
        if self.num_actors < 0:
            raise ValueError("num_actors must be >= 0")
        if self.max_restarts < 0 or self.restart_backoff_s < 0 or self.restart_backoff_max_s < 0:
            raise ValueError("restart settings must be >= 0")
        if not 0 < self.shutdown_grace_s <= 60:
            raise ValueError("shutdown_grace_s must be in (0, 60]")
        if self.liveness_timeout_s < 0 or self.liveness_grace_s < 0:
            raise ValueError("liveness_timeout_s and liveness_grace_s must be >= 0")


@dataclass
class DemoConfig:
    """Scripted demonstrations fed to the replay at the start of a run."""

    episodes: int = 10  #: demos per run (the paper's 10); 0 = none
    directory: str = "demos"  #: demos live in <directory>/<task>-<cameras>-<size>px/, shared by runs; made if missing
    seed: int = 0  #: seed of the first scripted demo
    every_n: int = 10  #: demo augmentation: a keyframe episode starts every this many control steps

    def __post_init__(self) -> None:
        if self.episodes < 0 or self.every_n < 1:
            raise ValueError("episodes must be >= 0 and every_n >= 1")


@dataclass
class RunConfig:
    """Every role's settings; one section per concern."""

    run: RunSection = field(default_factory=RunSection)  #: run identity, seed, run directory
    fabric: FabricConfig = field(default_factory=FabricConfig)  #: Zenoh router endpoints and transport
    launch: LaunchConfig = field(default_factory=LaunchConfig)  #: the single-machine launcher
    dashboard: DashboardConfig = field(default_factory=DashboardConfig)  #: the HTTP status dashboard
    replay: ReplayConfig = field(default_factory=ReplayConfig)  #: the replay server
    learner: LearnerConfig = field(default_factory=LearnerConfig)  #: the learner
    actor: ActorConfig = field(default_factory=ActorConfig)  #: actors and the evaluator
    sim: SimConfig = field(default_factory=SimConfig)  #: the PyBullet Panda task every actor steps
    robot: RobotConfig = field(default_factory=RobotConfig)  #: a real arm as one more actor (c2farm robot)
    demos: DemoConfig = field(default_factory=DemoConfig)  #: scripted demonstrations
    qattention: QAttentionConfig = field(default_factory=QAttentionConfig)  #: the C2F-ARM networks and loss (cameras, episode length and scene bounds come from sim)

    def __post_init__(self) -> None:
        if "robot" in self.launch.roles and not self.actor.scene_bounds_on_wire:
            raise ConfigError("actor.scene_bounds_on_wire: must be true in a run with a robot actor "
                              "(its episodes carry the robot's box; the replay wants every episode alike)")

    @property
    def run_dir(self) -> Path:
        if self.run.run_id is None:
            raise ConfigError("run.run_id: not set (pass --run-id; `c2farm launch` prints it)")
        return Path(self.run.runs_dir) / self.run.run_id


def find_preset(name: str) -> Path:
    """A preset by name (``cpu-small``) or by path (``my.yaml``)."""
    path = Path(name)
    if path.suffix in (".yaml", ".yml") and path.exists():
        return path
    for folder in PRESET_DIRS:
        candidate = folder / f"{name}.yaml"
        if candidate.exists():
            return candidate
    known = sorted({p.stem for d in PRESET_DIRS if d.is_dir() for p in d.glob("*.yaml")})
    raise ConfigError(f"preset {name!r} not found (known presets: {', '.join(known) or 'none'})")


def load_config(
    preset: Optional[str] = DEFAULT_PRESET,
    files: tuple[str | Path, ...] = (),
    overrides: tuple[dict, ...] = (),
) -> RunConfig:
    """Resolve defaults <- preset <- files <- overrides into a checked :class:`RunConfig`."""
    data: dict[str, Any] = {}
    if preset:
        data = merge(data, _checked(load_yaml(find_preset(preset)), f"preset {preset}"))
    for path in files:
        data = merge(data, _checked(load_yaml(path), str(path)))
    for override in overrides:
        data = merge(data, override)
    return from_dict(RunConfig, data)


def _checked(data: dict, origin: str) -> dict:
    try:
        from_dict(RunConfig, data)
    except ConfigError as exc:
        raise ConfigError(f"{origin}: {exc}") from None
    return data


def dump_yaml(config: RunConfig, docs: bool = False) -> str:
    """The resolved config as YAML; with ``docs`` every field carries its doc comment."""
    if not docs:
        return yaml.safe_dump(to_dict(config), sort_keys=False)
    lines: list[str] = []
    _dump_documented(config, 0, lines)
    return "\n".join(lines) + "\n"


def _dump_documented(obj: Any, indent: int, lines: list[str]) -> None:
    docs = field_docs(type(obj))
    pad = "  " * indent
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        doc = docs.get(f.name, "")
        if dataclasses.is_dataclass(value):
            lines.append(f"{pad}{f.name}:" + (f"  # {doc}" if doc else ""))
            _dump_documented(value, indent + 1, lines)
        else:
            text = yaml.safe_dump(to_dict(value), default_flow_style=True, width=10**6).strip()
            text = text.removesuffix("\n...").removesuffix("...").strip()
            lines.append(f"{pad}{f.name}: {text}" + (f"  # {doc}" if doc else ""))


def new_run_id() -> str:
    """A sortable, key-safe run id: ``YYYYmmdd-HHMMSS``."""
    return time.strftime("%Y%m%d-%H%M%S")


def write_run_dir(config: RunConfig, overwrite: bool = True) -> Path:
    """Create ``runs/<run-id>/`` with ``config.yaml`` and ``versions.json``; return it."""
    run_dir = config.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    config_path = run_dir / "config.yaml"
    if overwrite or not config_path.exists():
        config_path.write_text(dump_yaml(config), encoding="utf-8")
    versions_path = run_dir / "versions.json"
    if overwrite or not versions_path.exists():
        versions_path.write_text(json.dumps(versions(), indent=2) + "\n", encoding="utf-8")
    return run_dir


def versions() -> dict[str, Optional[str]]:
    """Versions of Python and the packages that shape results, plus the git commit."""
    out: dict[str, Optional[str]] = {"python": platform.python_version(), "platform": platform.platform()}
    for name, dist in (
        ("torch", "torch"),
        ("zenoh", "eclipse-zenoh"),
        ("pybullet", "pybullet"),
        ("ompl", "ompl"),
        ("numpy", "numpy"),
        ("pyzmq", "pyzmq"),
        ("c2farm", "c2farm"),
    ):
        try:
            out[name] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[name] = None
    try:
        result = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=5
        )
        out["git_commit"] = result.stdout.strip() or None
        dirty = subprocess.run(
            ["git", "status", "--porcelain"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=5
        )
        out["git_dirty"] = "yes" if dirty.stdout.strip() else "no"
    except (OSError, subprocess.SubprocessError):
        out["git_commit"] = None
    return out
