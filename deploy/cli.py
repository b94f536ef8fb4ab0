"""``c2farm``: one subcommand per role, plus ``launch`` that starts them all on this machine.

Every subcommand resolves the same typed config (see ``deploy/config.py``)::

    c2farm launch                                   # router, replay, learner, 2 actors, dashboard
    c2farm launch --actors 4 --run-id exp1 --set replay.capacity_transitions=50000
    c2farm router  --run-id exp1 --listen tcp/0.0.0.0:7447          # on the hub machine
    c2farm actor   --run-id exp1 --connect tcp/HUB:7447 --instance actor-7   # anywhere else
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path
from typing import Optional, Sequence

from deploy.config_loader import ConfigError, parse_override
from deploy.endpoints import free_port, loopback, wait_for_router
from deploy.liveness import PARENT_ENV, start_beacon_from_env, watch_parent
from actors.sim.task_names import DEFAULT_TASK, TASKS

log = logging.getLogger("c2farm")

#: one subcommand per role: its help line
ROLE_HELP = {
    "router": "run the Zenoh router (the hub every other role connects to)",
    "replay": "run the replay server (stores episodes, serves batches to the learner)",
    "learner": "run the learner (trains the Q-attention cascade, broadcasts weights)",
    "actor": "run one actor (steps the PyBullet Panda task, sends episodes)",
    "eval": "run the evaluator (greedy policy on fixed seeds, once per weights version)",
    "demo_source": "publish the run's scripted demos to the replay (generating them if missing)",
    "dashboard": "run the HTTP dashboard (GET /, /api/status, /healthz, /metrics)",
    "robot": "run a robot actor: a real arm (Franka via franky) or franky-sim, a person giving reward",
}

DESCRIPTION = """\
C2F-ARM (coarse-to-fine Q-attention) as a distributed actor-learner service.

Roles: a Zenoh router (the hub), a replay server, a learner, N actors, an evaluator, a
demo source and a dashboard. `c2farm launch` starts all of them on this machine; the other
subcommands start one role by hand, e.g. on another machine pointed at the hub with
--connect. `c2farm demos` writes scripted demonstrations as MCAP files.

Configuration: defaults <- --preset <- --config FILE <- flags <- --set section.key=value.
See the resolved config (every key, documented) with `c2farm launch --print-config`.
"""


# -- argument parsing --------------------------------------------------------------------


def _common(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("configuration (shared by every subcommand)")
    g.add_argument(
        "--preset",
        default="cpu-small",
        metavar="NAME",
        help="preset from configs/ (cpu-small: this 2-core machine, paper: the paper's settings) "
        "or a path to a YAML file; 'none' for bare defaults (default: %(default)s)",
    )
    g.add_argument(
        "--config",
        action="append",
        default=[],
        metavar="FILE",
        help="YAML file merged over the preset, e.g. runs/<run-id>/config.yaml (repeatable)",
    )
    g.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one key; the value is read as YAML (e.g. --set replay.compression=lz4, "
        "--set fabric.connect=[tcp/10.0.0.2:7447]); repeatable, applied last",
    )
    g.add_argument("--run-id", metavar="ID", help="run name; all roles of a run must share it (run.run_id)")
    g.add_argument("--seed", type=int, metavar="N", help="base random seed (run.seed)")
    g.add_argument("--runs-dir", metavar="DIR", help="parent of run directories (run.runs_dir, default runs)")
    g.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh router endpoint(s) this process dials, e.g. tcp/10.0.0.2:7447 (fabric.connect; repeatable)",
    )
    g.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint(s) the router listens on, e.g. tcp/0.0.0.0:7447 (fabric.listen; repeatable). "
        "Without --connect, local roles dial the same port on 127.0.0.1",
    )
    g.add_argument(
        "--shm",
        dest="shared_memory",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="Zenoh same-host shared-memory transport (fabric.shared_memory; default on)",
    )
    g.add_argument(
        "--print-config",
        action="store_true",
        help="print the resolved config with a comment on every key, then exit",
    )
    g.add_argument("--task", metavar="NAME",
                   help=f"task every actor steps (sim.task): {', '.join(TASKS)} (default: {DEFAULT_TASK})")
    g.add_argument("--log-level", default="INFO", help="Python log level (default: %(default)s)")


def _robot_flags(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("robot actor")
    g.add_argument("--robot", choices=("franka", "franky-sim"), help="the arm (robot.arm); on launch, also starts a robot actor")
    g.add_argument("--robot-host", metavar="HOST", help="the Franka's FCI address (robot.franka.host)")
    g.add_argument("--camera", action="append", metavar="KIND[:SERIAL]",
                   help="an RGB-D camera, e.g. realsense:123456 or mujoco (robot.cameras; repeatable, named "
                   "front, left_shoulder, ... in order)")


def build_parser(demo_options: bool = True) -> argparse.ArgumentParser:
    """The ``c2farm`` parser. ``demo_options=False`` leaves out the ``demos`` options, whose
    import pulls in the simulator: a role process (the router, the dashboard) starts faster."""
    from deploy.config import DEFAULT_INSTANCE, DEFAULT_ROLES  # imports every role's config

    parser = argparse.ArgumentParser(
        prog="c2farm", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser(
        "launch",
        help="start every role on this machine and supervise them",
        description="Start the Zenoh router, replay server, dashboard, learner, demo source, N actors "
        "and the evaluator as separate processes; stream their logs with a role prefix; restart every "
        "role that dies or goes silent (the demo source only if it failed); stop everything on "
        "Ctrl-C / SIGTERM. Writes runs/<run-id>/config.yaml and versions.json.",
    )
    _common(p)
    p.add_argument("--actors", type=int, metavar="N", help="number of actor processes (launch.num_actors)")
    p.add_argument(
        "--roles",
        metavar="LIST",
        help="comma-separated roles to start here (launch.roles), e.g. 'actor' on an extra actor "
        f"machine with --connect tcp/HUB:7447; default: {','.join(DEFAULT_ROLES)} (--robot adds robot)",
    )
    p.add_argument(
        "--router-port",
        type=int,
        metavar="PORT",
        help="shortcut: router listens on, and roles dial, tcp/127.0.0.1:PORT (0 picks a free port)",
    )
    _robot_flags(p)
    p.add_argument("--dashboard-host", metavar="HOST", help="dashboard bind address (dashboard.host)")
    p.add_argument(
        "--dashboard-port", type=int, metavar="PORT", help="dashboard port (dashboard.port; 0 picks a free one)"
    )

    for role, text in ROLE_HELP.items():
        p = sub.add_parser(role, help=text, description=text[0].upper() + text[1:] + ".")
        _common(p)
        p.add_argument(
            "--instance",
            metavar="NAME",
            default=DEFAULT_INSTANCE[role],
            help="unique name of this process within its role (default: %(default)s)",
        )
        if role == "robot":
            _robot_flags(p)
        if role == "dashboard":
            p.add_argument("--host", metavar="HOST", help="bind address (dashboard.host, default 127.0.0.1)")
            p.add_argument("--port", type=int, metavar="PORT", help="HTTP port (dashboard.port, default 8080)")
    p = sub.add_parser(
        "demos",
        help="write scripted demonstrations of a task as MCAP files",
        description="Run a task's scripted waypoints through the control agent and record every "
        "control step as one MCAP file per episode (opens in Foxglove).",
    )
    if demo_options:
        from actors.demos.cli import add_arguments

        add_arguments(p)
    p = sub.add_parser(
        "robot-demos",
        help="record demonstrations on the robot from the operator's waypoints (MCAP, as simulated demos)",
        description="Drive the configured arm (robot.arm) through waypoints 'x y z [qx qy qz qw] open|close [via]', "
        "one per line, recording every demo into the run's demo folder, where the demo source sends it from. "
        "Each waypoint's end is a keyframe the agent learns from, except a via-point's (a trailing 'via': "
        "only there to steer the path); the last waypoint cannot be one. On franky-sim with "
        "robot.scripted_operator=true the scripted operator demonstrates its reach task instead (no waypoints).",
    )
    _common(p)
    _robot_flags(p)
    p.add_argument("--waypoints", metavar="FILE", help="waypoints file; default: type them in the terminal, "
                   "an empty line ends")
    p.add_argument("--episodes", type=int, metavar="N", help="demos to record (demos.episodes; the paper: 3 per real task)")
    return parser


def overrides_from_args(args: argparse.Namespace) -> list[dict]:
    """First-class flags as config overrides, then every ``--set``."""
    out: dict = {}

    def put(section: str, key: str, value) -> None:
        if value is not None:
            out.setdefault(section, {})[key] = value

    put("sim", "task", args.task)
    put("robot", "arm", getattr(args, "robot", None))
    if getattr(args, "robot", None):  # the robot's depth-0 box is not the task's: every episode says its own
        put("actor", "scene_bounds_on_wire", True)
    if getattr(args, "robot_host", None):
        out.setdefault("robot", {}).setdefault("franka", {})["host"] = args.robot_host
    if getattr(args, "camera", None):
        from protocol.observation import CAMERA_NAMES

        if len(args.camera) > len(CAMERA_NAMES):
            raise ConfigError(f"--camera: given {len(args.camera)} times, but an observation has at most "
                              f"{len(CAMERA_NAMES)} cameras ({', '.join(CAMERA_NAMES)}, in --camera order)")
        cams = []
        for name, text in zip(CAMERA_NAMES, args.camera):
            kind, _, serial = text.partition(":")
            cams.append({"name": name, "kind": kind, "serial": serial})
        put("robot", "cameras", cams)
    put("run", "run_id", args.run_id)
    put("run", "seed", args.seed)
    put("run", "runs_dir", args.runs_dir)
    put("fabric", "shared_memory", args.shared_memory)
    listen = args.listen
    if getattr(args, "router_port", None) is not None:
        port = args.router_port or free_port()
        listen = listen or [f"tcp/127.0.0.1:{port}"]
    if listen:
        put("fabric", "listen", listen)
        if not args.connect:
            put("fabric", "connect", [loopback(e) for e in listen])
    put("fabric", "connect", args.connect)
    put("launch", "num_actors", getattr(args, "actors", None))
    roles = getattr(args, "roles", None)
    if roles is not None:
        put("launch", "roles", [r.strip() for r in roles.split(",") if r.strip()])
    put("dashboard", "host", getattr(args, "dashboard_host", None) or getattr(args, "host", None))
    port = getattr(args, "dashboard_port", None)
    port = port if port is not None else getattr(args, "port", None)
    put("dashboard", "port", port)
    return [out] + [parse_override(text) for text in args.overrides]


def with_robot_role(args: argparse.Namespace, config) -> None:
    """``c2farm launch --robot ...`` also starts a robot actor (unless --roles said otherwise)."""
    if args.command == "launch" and getattr(args, "robot", None) and getattr(args, "roles", None) is None:
        if "robot" not in config.launch.roles:
            config.launch.roles.append("robot")


# -- running a role ----------------------------------------------------------------------


def run_role(role: str, config, instance: str) -> int:
    """Run one role in this process until it is told to stop; return its exit code."""
    from deploy.roles import ROLES
    from protocol.role import RoleContext, stop_on_signals

    ctx = RoleContext(
        run_id=config.run.run_id,
        instance=instance,
        run_dir=config.run_dir,
        seed=config.run.seed,
        fabric=config.fabric,
    )
    stop_on_signals(ctx.stop)
    if os.environ.get(PARENT_ENV):
        watch_parent(int(os.environ[PARENT_ENV]), ctx.stop)
    if role != "router" and not wait_for_router(config.fabric.connect, config.launch.router_wait_s, ctx.stop):
        if ctx.stop.is_set():
            return 0
        log.error("no Zenoh router answers on %s (start `c2farm router` or `c2farm launch` first)",
                  ", ".join(config.fabric.connect))
        return 2
    entry = ROLES[role][0]
    log.info("%s %s starting (run %s, pid %d)", role, instance, ctx.run_id, os.getpid())
    code = entry(config, ctx)
    log.info("%s %s stopped (exit %s)", role, instance, code)
    return int(code or 0)


# -- main --------------------------------------------------------------------------------


def main(argv: Optional[Sequence[str]] = None) -> int:
    start_beacon_from_env()  # a role started by the launcher: its liveness check counts from now
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(demo_options=not argv or argv[0] not in ROLE_HELP).parse_args(argv)
    if args.command == "demos":
        from actors.demos.cli import run

        return run(args)
    logging.basicConfig(
        level=getattr(logging, str(args.log_level).upper(), logging.INFO),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
    from deploy import config as cfg_mod

    try:
        config = cfg_mod.load_config(
            preset=None if args.preset == "none" else args.preset,
            files=tuple(args.config),
            overrides=tuple(overrides_from_args(args)),
        )
        with_robot_role(args, config)
        if args.command == "launch" and config.run.run_id is None:
            config.run.run_id = _unique_run_id(cfg_mod, Path(config.run.runs_dir))
        if args.command == "launch" and "dashboard" in config.launch.roles and config.dashboard.port == 0:
            config.dashboard.port = free_port()
        if args.print_config:
            sys.stdout.write(cfg_mod.dump_yaml(config, docs=True))
            return 0
        if args.command == "robot-demos":  # writes demo files, joins no run
            return _robot_demos(args, config)
        if config.run.run_id is None:
            raise ConfigError(
                "run.run_id: not set; every role of a run needs the same --run-id (`c2farm launch` prints it)"
            )
    except ConfigError as exc:
        print(f"c2farm: config error: {exc}", file=sys.stderr)
        return 2
    from deploy.preflight import problems

    found = problems(config, list(config.launch.roles) if args.command == "launch" else [args.command])
    for problem in found:
        print(f"c2farm: cannot start: {problem}", file=sys.stderr)
    if found:
        return 2

    if args.command == "launch":
        from deploy.launch import Launcher

        cfg_mod.write_run_dir(config, overwrite=True)
        return Launcher(config).run()
    cfg_mod.write_run_dir(config, overwrite=False)
    try:
        return run_role(args.command, config, args.instance)
    except ValueError as exc:  # a bad instance name
        print(f"c2farm: {exc}", file=sys.stderr)
        return 2


def _robot_demos(args, config) -> int:
    """``c2farm robot-demos``: the operator's waypoints, recorded on the arm into the run's demo folder."""
    from actors.robot.demos import read_waypoints, record_demos
    from deploy.roles import demo_dir

    try:
        if config.robot.scripted_operator:  # franky-sim: the scripted operator demonstrates its reach task
            waypoints = []
        elif args.waypoints:
            waypoints = read_waypoints(Path(args.waypoints).read_text().splitlines())
        else:
            print("waypoints, one per line: x y z [qx qy qz qw] open|close [via]; an empty line ends", flush=True)
            waypoints = _typed_waypoints()
    except (OSError, ValueError) as exc:  # a missing file or a bad line: one line, before the arm moves
        print(f"c2farm: {exc}", file=sys.stderr)
        return 2
    if not waypoints and not config.robot.scripted_operator:
        print("c2farm: no waypoints", file=sys.stderr)
        return 2
    written = record_demos(config, waypoints, args.episodes or config.demos.episodes, demo_dir(config))
    print(f"{len(written)} robot demos in {demo_dir(config)}")
    return 0


def _typed_waypoints() -> list:
    """Waypoints typed in the terminal until an empty line; a mistyped line is said and typed again."""
    from actors.robot.demos import parse_waypoint, read_waypoints

    lines: list[str] = []
    for line in iter(lambda: sys.stdin.readline().rstrip("\n"), ""):
        try:
            parse_waypoint(line)
        except ValueError as exc:
            print(f"{exc}; type it again", flush=True)
            continue
        lines.append(line)
    return read_waypoints(lines)


def _unique_run_id(cfg_mod, runs_dir: Path) -> str:
    base = cfg_mod.new_run_id()
    run_id, n = base, 1
    while (runs_dir / run_id).exists():
        n += 1
        run_id = f"{base}-{n}"
    return run_id


def exit_now(code: int) -> None:
    """Flush, then end the process without interpreter teardown.

    Everything a role owns (sessions, sockets, checkpoints, logs) is closed by the time its
    entry point returns; what is left is tearing down torch and Zenoh's modules, which took
    0.5 s idle and several seconds on a busy 2-core machine: time the launcher's 10 s stop
    cannot spare. Only for ``python -m deploy.cli`` (the launcher's children, and the launcher
    itself there), never for a caller that imported ``main``.
    """
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


if __name__ == "__main__":
    exit_now(main())
