"""``c2farm``'s command line: a subcommand per role, ``launch`` and the demo commands; flags become config overrides.

Parsing only: nothing here starts anything. ``deploy/cli.py`` resolves the config from what
this returns and runs the command.
"""

from __future__ import annotations

import argparse

from actors.sim.task_specs import DEFAULT_TASK, TASKS
from deploy.config_loader import ConfigError, parse_override
from deploy.endpoints import free_port, loopback

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
        "--certs",
        metavar="DIR",
        help="keys made by `c2farm certs`: TLS with mutual authentication on every Zenoh link, access control at "
        "the router, CURVE on the learner <-> replay link (fabric.certs)",
    )
    g.add_argument(
        "--insecure",
        action="store_true",
        default=None,
        help="allow plain TCP beyond loopback without --certs: every host that reaches the router is trusted "
        "(fabric.insecure)",
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
    g.add_argument("--foxglove", nargs="?", type=int, const=8765, metavar="PORT",
                   help="serve the evaluator's (or the robot actor's) scene and each decision's attention live to "
                   "Foxglove on ws://127.0.0.1:PORT (actor.foxglove_port; PORT defaults to 8765, 0 picks a free one)")
    g.add_argument("--log-level", default="INFO", help="Python log level (default: %(default)s)")


def _policy_flags(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("an exported policy instead of a run (no router, no other role)")
    g.add_argument("--policy", metavar="DIR", help="act greedily with the policy `c2farm export policy` wrote in DIR "
                   "and print its success rate; joins no run")
    g.add_argument("--episodes", type=int, metavar="N",
                   help="with --policy: greedy episodes to run, exactly (default: actor.eval_episodes)")


def _robot_flags(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("robot actor")
    g.add_argument(
        "--robot", choices=("franka", "franky-sim"), help="the arm (robot.arm); on launch, also starts a robot actor"
    )
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
        if role in ("eval", "robot"):
            _policy_flags(p)
        if role == "dashboard":
            p.add_argument("--host", metavar="HOST", help="bind address (dashboard.host, default 127.0.0.1)")
            p.add_argument("--port", type=int, metavar="PORT", help="HTTP port (dashboard.port, default 8080)")
    p = sub.add_parser(
        "certs",
        help="make the keys a run needs beyond loopback (TLS certificates, access identities, CURVE keys)",
        description="Create a certificate authority, a TLS certificate per role process (its common name, "
        "role.instance, is what the router's access control judges) and the CURVE key pairs of the learner <-> "
        "replay link, in DIR. Run again with more --actors or --identity to add identities; what exists is kept. "
        "Copy ca.pem and a host's own certificate and key to that host; keep ca.key on the hub.",
    )
    p.add_argument("directory", metavar="DIR", help="where the keys go (created with private permissions)")
    p.add_argument("--hub", action="append", default=[], metavar="HOST",
                   help="an address or name actor hosts dial the router by (repeatable; 127.0.0.1 and localhost "
                   "are always in)")
    p.add_argument("--actors", type=int, default=2, metavar="N", help="actor identities actor-0..N-1 (default 2)")
    p.add_argument("--instance-prefix", default="", metavar="PREFIX",
                   help="prefix of those actors' instance names, as launch.instance_prefix on their host")
    p.add_argument("--identity", action="append", default=[], metavar="ROLE.INSTANCE",
                   help="one more identity, e.g. robot.robot-0 or actor.box3-actor-0 (repeatable)")
    p.add_argument("--days", type=int, default=365, metavar="N", help="validity of new certificates (default 365)")
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
    p.add_argument(
        "--episodes", type=int, metavar="N", help="demos to record (demos.episodes; the paper: 3 per real task)"
    )
    _interchange(sub)
    return parser


def _interchange(sub) -> None:
    """``export`` and ``import``: policies and episodes in the formats other tools read."""
    p = sub.add_parser("export", help="write a trained policy, or demos and episodes, for other tools",
                       description="Write what other tools read: a portable policy (safetensors + config.json) "
                       "or a LeRobot dataset (v3.0 layout) of demos or of a run's episodes.")
    what = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    q = what.add_parser("policy", help="the online networks and what acting needs, out of a run directory",
                        description="Write model.safetensors (the online networks only) and config.json (Q-attention "
                        "config, cameras, scene bounds, task, weights version, learner step, code version) into DIR.")
    q.add_argument("run_dir", metavar="RUN_DIR", help="the run directory (runs/<run-id>)")
    q.add_argument("--out", required=True, metavar="DIR", help="where the policy goes")
    q.add_argument("--checkpoint", metavar="FILE", help="a learner checkpoint file (default: the run's latest)")
    q = what.add_parser("lerobot", help="demos or a run's episodes as a LeRobot dataset (v3.0 layout)",
                        description="Write a LeRobotDataset (meta/, data/chunk-XXX/file-XXX.parquet, images per "
                        "camera) of MCAP demos or of a run's recorded episodes.")
    source = q.add_mutually_exclusive_group(required=True)
    source.add_argument("--demos", metavar="DIR", help="a folder of MCAP demo files")
    source.add_argument("--run", metavar="RUN_DIR", help="a run directory: its recorded episodes")
    q.add_argument("--episodes", choices=("eval", "train"), default="eval",
                   help="with --run: the evaluator's or the actors' episodes (default: %(default)s)")
    q.add_argument("--out", required=True, metavar="DIR", help="the dataset's root (created; must be empty)")
    q.add_argument("--repo-id", metavar="NAME", help="the dataset's name in meta/info.json (default: the folder's)")
    p = sub.add_parser("import", help="turn another tool's dataset into demo files the demo source sends",
                       description="Read a LeRobot dataset that carries depth or point clouds and camera matrices "
                       "and write one MCAP demo file per episode; say in one line what is missing otherwise.")
    what = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    q = what.add_parser("lerobot", help="a LeRobot dataset (v3.0 layout) into MCAP demo files")
    q.add_argument("dataset", metavar="DIR", help="the dataset's root folder")
    q.add_argument("--out", required=True, metavar="DIR", help="where the demo files go")
    q.add_argument("--task", metavar="TASK", help="the task name the demos are for (default: the dataset's)")


def overrides_from_args(args: argparse.Namespace) -> list[dict]:
    """First-class flags as config overrides, then every ``--set``."""
    out: dict = {}

    def put(section: str, key: str, value) -> None:
        if value is not None:
            out.setdefault(section, {})[key] = value

    put("sim", "task", args.task)
    put("actor", "foxglove_port", getattr(args, "foxglove", None))
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
    put("fabric", "certs", getattr(args, "certs", None))
    put("fabric", "insecure", getattr(args, "insecure", None))
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
