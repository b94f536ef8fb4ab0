"""What can be checked before a role starts, checked once: one line per problem, exit code 2.

A launch with a task that does not exist used to start every role, which then crash-looped
for minutes while the launcher reported success. Here the task, the cameras, the ports this
machine must listen on and the directories it must write are checked up front, for
``c2farm launch`` (every role it starts) and for a single role started by hand.
"""

from __future__ import annotations

import json
import socket
import tempfile
from pathlib import Path

from deploy.endpoints import tcp_endpoints
from qattention.config import QAttentionConfig

#: Roles that build a simulated task (and so need a known task and cameras).
SIM_ROLES = frozenset({"actor", "eval", "demo_source"})


def problems(config, roles: list[str], instance: str | None = None) -> list[str]:
    """Everything wrong with starting ``roles`` of ``config`` on this machine, one line each.

    ``instance`` names the one process of a role started by hand; for a launch, the
    instances are the launcher's (``launch.instance_prefix``, ``launch.num_actors``).
    """
    found: list[str] = []
    if config.fabric.secure:
        found += _certificates(config, roles, instance)
    if SIM_ROLES & set(roles):
        from actors.sim.task_specs import TASKS

        if config.sim.task not in TASKS:
            found.append(f"sim.task: unknown task {config.sim.task!r}; choose from {', '.join(TASKS)}")
    # Every role fuses sim.cameras (deploy.roles.network_config): a qattention.cameras of its own would be
    # silently replaced, so one that is neither the default nor sim's is refused rather than ignored.
    cameras = tuple(config.qattention.cameras)
    if cameras not in (QAttentionConfig().cameras, tuple(config.sim.cameras)):
        found.append(f"qattention.cameras: {list(cameras)} is not used, every role fuses sim.cameras "
                     f"({list(config.sim.cameras)}); set sim.cameras instead")
    if "router" in roles:
        for host, port in tcp_endpoints(config.fabric.listen):
            found += _port_free(host, port, "fabric.listen (the Zenoh router)")
    if "dashboard" in roles and config.dashboard.port:
        found += _port_free(config.dashboard.host, config.dashboard.port, "dashboard.port")
    if "replay" in roles:
        endpoint = config.replay.zmq_endpoint.replace("tcp://", "tcp/", 1)
        for host, port in tcp_endpoints([endpoint]):
            found += _port_free("127.0.0.1" if host == "*" else host, port, "replay.zmq_endpoint")
    found += _writable(Path(config.run.runs_dir), "run.runs_dir")
    found += _same_scene(config)
    if "demo_source" in roles and config.demos.episodes > 0:
        found += _writable(Path(config.demos.directory), "demos.directory")
    return found


def _certificates(config, roles: list[str], instance: str | None) -> list[str]:
    """Each process's certificate exists, is private, current and signed by the run's authority."""
    from deploy.certs import check_certificate, identity
    from deploy.config import DEFAULT_INSTANCE

    launch = config.launch
    names = []
    for role in roles:
        if instance is not None:
            names.append(identity(role, instance))
        elif role == "actor":
            names += [identity(role, f"{launch.instance_prefix}actor-{i}") for i in range(launch.num_actors)]
        else:
            names.append(identity(role, launch.instance_prefix + DEFAULT_INSTANCE[role]))
    found = []
    for name in names:
        try:
            check_certificate(Path(config.fabric.certs), name)
        except ValueError as exc:
            found.append(f"fabric.certs: {exc}")
    return found


def _same_scene(config) -> list[str]:
    """A run resumes only on the task (and scene revision) it started on.

    Its checkpoints hold the replay and weights of that scene; a run id reused after a task's
    revision changed (say stack_wine's layout) would otherwise resume them silently.
    """
    import yaml

    from deploy.config import TASK_RECORD, task_record

    run_dir = config.run_dir
    now = task_record(config)
    try:
        if (run_dir / TASK_RECORD).exists():
            started = json.loads((run_dir / TASK_RECORD).read_text(encoding="utf-8"))
        elif (run_dir / "config.yaml").exists():  # a run older than the record: its task, revision unknown
            previous = yaml.safe_load((run_dir / "config.yaml").read_text(encoding="utf-8"))
            started = {"task": previous["sim"]["task"], "revision": now["revision"]}
        else:
            return []
        same = (started["task"], started["revision"]) == (now["task"], now["revision"])
    except (OSError, ValueError, KeyError, TypeError, yaml.YAMLError) as exc:
        return [f"run.run_id: cannot tell which task {str(run_dir)!r} started on ({exc}); choose a new --run-id"]
    if same:
        return []

    def scene(record: dict) -> str:
        return f"{record['task']} revision {record['revision']}" if record["revision"] else str(record["task"])

    return [f"run.run_id: {str(run_dir)!r} holds a run of {scene(started)}, not {scene(now)}: resuming it would "
            f"carry that scene's replay and weights over; choose a new --run-id"]


def _port_free(host: str, port: int, what: str) -> list[str]:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a port in TIME_WAIT is free to listen on
        try:
            sock.bind((host, port))
        except OSError as exc:
            return [f"{what}: cannot listen on {host}:{port} ({exc.strerror or exc}); is another run using it?"]
    return []


def _writable(directory: Path, what: str) -> list[str]:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as exc:
        return [f"{what}: cannot write to {str(directory)!r} ({exc.strerror or exc})"]
    return []
