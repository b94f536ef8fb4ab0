"""The one typed config of a run: a section per concern, loaded from YAML, overridable, saved.

Resolution order (later wins): dataclass defaults -> preset (``configs/<name>.yaml``) ->
``--config FILE`` -> first-class CLI flags (``--actors``, ``--connect`` ...) -> ``--set a.b=v``.
The resolved config is written to ``runs/<run-id>/config.yaml``; every role process the
launcher starts reads that same file, so all of them agree.

Adding a section is one line in :class:`RunConfig` (its dataclass lives with its role).
Every section checks its fields' ranges when built (``protocol/config_checks.py``), and
:func:`check_across_sections` the rules that tie sections together, so a bad value is one
:class:`ConfigError` line when the config is resolved, before any process starts.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import subprocess
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any, Optional

import yaml

from actors.config import ActorConfig
from actors.robot.config import RobotConfig
from actors.sim.config import SimConfig
from dashboard.config import DashboardConfig
from deploy.config_loader import ConfigError, field_docs, from_dict, load_yaml, merge, to_dict
from learner.config import LearnerConfig
from protocol import keys
from protocol.config_checks import above, at_least, endpoint_host, is_loopback_host, non_empty, within
from protocol.fabric import FabricConfig
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
    seed: int = 0  #: base random seed, >= 0; every role derives its own streams from it
    runs_dir: str = "runs"  #: parent folder of run directories (runs/<run-id>/); not empty

    def __post_init__(self) -> None:
        if self.run_id is not None:
            keys.check_id(self.run_id, "run id")
        at_least(self, 0, "seed")
        non_empty(self, "runs_dir")


@dataclass
class LaunchConfig:
    """What `c2farm launch` starts on this machine and how it supervises it."""

    #: roles started here (at least one; others run elsewhere); add robot for a robot actor
    roles: list[str] = field(default_factory=lambda: list(DEFAULT_ROLES))
    num_actors: int = 2  #: actor processes to start, >= 0
    #: prepended to the instance names started here, e.g. "box3-" (unique per machine; letters, digits, '_', '.', '-')
    instance_prefix: str = ""
    #: roles restarted when their process dies or goes silent (one-shot roles only on failure)
    restart: list[str] = field(
        default_factory=lambda: list(ROLES)
    )
    #: print a progress line (updates, env steps, eval success) this often, seconds, >= 0; 0 = never
    progress_every_s: float = 30.0
    #: wait before restarting an instance, seconds, >= 0; doubles per quick failure in a row
    restart_backoff_s: float = 1.0
    #: ceiling of the restart wait, seconds, >= 0; an instance that ran this long starts the doubling afresh
    restart_backoff_max_s: float = 30.0
    max_restarts: int = 20  #: restarts per instance before the launcher gives up on it, >= 0
    #: a role whose beacon (runs/<id>/heartbeats/) is silent this long (seconds, >= 0) is killed and restarted; 0 =
    #: never
    liveness_timeout_s: float = 15.0
    #: a just-started role is not judged silent for this long, seconds, >= 0 (slow imports on a busy machine)
    liveness_grace_s: float = 60.0
    #: one deadline for the whole stop, seconds, in (0, 60]: SIGTERM all, SIGKILL what is left after it (stop < 10 s)
    shutdown_grace_s: float = 8.0
    router_wait_s: float = 20.0  #: how long roles wait for the Zenoh router to accept connections, seconds, > 0
    #: how long the launcher waits for the dashboard to serve before starting the roles it watches, seconds,
    #: >= 0 (0: no wait); a one-shot role such as the demo source may finish before a late dashboard listens
    dashboard_wait_s: float = 30.0

    def __post_init__(self) -> None:
        for role in list(self.roles) + list(self.restart):
            if role not in ROLES:
                raise ValueError(f"unknown role {role!r}; roles are {', '.join(ROLES)}")
        non_empty(self, "roles")
        if self.instance_prefix and not keys.is_valid_id(self.instance_prefix + "x"):
            raise ValueError(f"instance_prefix must start with a letter or digit and hold only letters, digits, "
                             f"'_', '.', '-' (got {self.instance_prefix!r})")
        at_least(self, 0, "num_actors", "max_restarts", "progress_every_s", "restart_backoff_s",
                 "restart_backoff_max_s", "liveness_timeout_s", "liveness_grace_s", "dashboard_wait_s")
        within(self, 0, 60, "shutdown_grace_s", open_low=True)
        above(self, 0, "router_wait_s")


@dataclass
class DemoConfig:
    """Scripted demonstrations fed to the replay at the start of a run."""

    episodes: int = 10  #: demos per run, >= 0 (the paper's 10); 0 = none
    #: demos live in <directory>/<task>-<cameras>-<size>px/, shared by runs; made if missing; not empty
    directory: str = "demos"
    seed: int = 0  #: seed of the first scripted demo, >= 0
    every_n: int = 10  #: demo augmentation: a keyframe episode starts every this many control steps, >= 1
    #: each augmented episode but frame 0's stops after this many keyframes, >= 0; 0 = runs to the demo's end (the
    #: authors'), 1 = every distinct keyframe jump stored once (long demos: their first keyframes sampled as often)
    chain_keyframes: int = 0

    def __post_init__(self) -> None:
        at_least(self, 0, "episodes", "seed", "chain_keyframes")
        at_least(self, 1, "every_n")
        non_empty(self, "directory")


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
    #: the C2F-ARM networks and loss (cameras, episode length and scene bounds come from sim)
    qattention: QAttentionConfig = field(default_factory=QAttentionConfig)

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
    config = from_dict(RunConfig, data)
    check_across_sections(config)
    return config


def check_across_sections(config: RunConfig) -> None:
    """Rules that tie two sections together (each section checks its own fields' ranges when
    built); checked on the resolved config, so a file may set one side and --set the other."""
    learner, replay = config.learner, config.replay
    if learner.batch_size > replay.max_batch_size:
        raise ConfigError(f"learner.batch_size must be <= replay.max_batch_size ({replay.max_batch_size}), "
                          f"or the replay refuses every batch (got {learner.batch_size})")
    if replay.samples_per_insert > 0 and replay.samples_per_insert_error_buffer < learner.batch_size:
        raise ConfigError(
            f"replay.samples_per_insert_error_buffer must be >= learner.batch_size ({learner.batch_size}) "
            f"when replay.samples_per_insert > 0 (got {replay.samples_per_insert_error_buffer:g})"
        )
    if replay.min_size_to_sample > replay.capacity_transitions:
        raise ConfigError(
            f"replay.min_size_to_sample must be <= replay.capacity_transitions "
            f"({replay.capacity_transitions}), or sampling never starts (got {replay.min_size_to_sample})"
        )
    plain = not (config.fabric.certs or config.fabric.insecure)
    for name, endpoint, keyed in (("replay.zmq_endpoint", replay.zmq_endpoint, replay.curve_certificate),
                                  ("learner.replay_endpoint", learner.replay_endpoint, learner.curve_certificate)):
        host = endpoint_host(endpoint) if endpoint else None  # "*" binds every interface
        if plain and not keyed and host is not None and not is_loopback_host(host):
            raise ConfigError(f"{name} {endpoint} is beyond loopback: pass --certs DIR (CURVE on the learner <-> "
                              "replay link) or --insecure to let anyone who reaches it sample batches")
    if not config.sim.cameras:
        raise ConfigError("sim.cameras must name at least one camera: the networks see the scene through them (got [])")


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


#: The task and scene revision a run started on, written once, when its directory is new: resumed on another
#: scene, its checkpoints would carry the old scene's replay and weights into the new one (deploy/preflight.py).
TASK_RECORD = "task.json"


def task_record(config: RunConfig) -> dict[str, Any]:
    """``{"task": ..., "revision": ...}`` of ``config``; the revision is None for a task the ladder lacks."""
    from actors.sim.task_specs import TASK_SPECS

    spec = TASK_SPECS.get(config.sim.task)
    return {"task": config.sim.task, "revision": spec.revision if spec else None}


def write_run_dir(config: RunConfig, overwrite: bool = True) -> Path:
    """Create ``runs/<run-id>/`` with ``config.yaml``, ``versions.json`` and, when new, ``task.json``; return it."""
    run_dir = config.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    config_path = run_dir / "config.yaml"
    if not config_path.exists() and not (run_dir / TASK_RECORD).exists():
        (run_dir / TASK_RECORD).write_text(json.dumps(task_record(config)) + "\n", encoding="utf-8")
    if overwrite or not config_path.exists():
        config_path.write_text(dump_yaml(config), encoding="utf-8")
    versions_path = run_dir / "versions.json"
    if overwrite or not versions_path.exists():
        versions_path.write_text(json.dumps(versions(), indent=2) + "\n", encoding="utf-8")
    return run_dir


#: CPU flags that change a run's speed several-fold (bf16 is native only with avx512_bf16 / amx_bf16).
SPEED_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_bf16", "amx_tile")


def cpu() -> str:
    """The CPU as a run's record names it: model, logical cores and the flags of ``SPEED_FLAGS`` it has.

    Hosts of one kind differ (an "AMD EPYC" VM with AVX2 only, another with AVX-512-bf16), so the
    model name alone does not say how fast a learner was.
    """
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return f"{platform.processor() or 'unknown'}, {os.cpu_count()} cores"
    fields = dict(line.split(":", 1) for line in text.splitlines() if ":" in line)
    fields = {k.strip(): v.strip() for k, v in fields.items()}
    flags = set(fields.get("flags", "").split())
    have = " ".join(f for f in SPEED_FLAGS if f in flags) or "no avx2"
    return f"{fields.get('model name', 'unknown')}, {os.cpu_count()} cores, {have}"


def versions() -> dict[str, Optional[str]]:
    """Versions of Python and the packages that shape results, the CPU, and the git commit."""
    out: dict[str, Optional[str]] = {"python": platform.python_version(), "platform": platform.platform(),
                                     "cpu": cpu()}
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
