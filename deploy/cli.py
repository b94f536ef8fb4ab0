"""``c2farm``: one subcommand per role, plus ``launch`` that starts them all on this machine.

Every subcommand resolves the same typed config (see ``deploy/config.py``)::

    c2farm launch                                   # router, replay, learner, 2 actors, dashboard
    c2farm launch --actors 4 --run-id exp1 --set replay.capacity_transitions=50000
    c2farm router  --run-id exp1 --listen tcp/0.0.0.0:7447          # on the hub machine
    c2farm actor   --run-id exp1 --connect tcp/HUB:7447 --instance actor-7   # anywhere else
"""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
from pathlib import Path
from typing import Optional, Sequence

from deploy.certs import identity
from deploy.config_loader import ConfigError
from deploy.endpoints import free_port, wait_for_listener
from deploy.liveness import PARENT_ENV, start_beacon_from_env, watch_parent
from deploy.parser import ROLE_HELP, build_parser, overrides_from_args, with_robot_role

log = logging.getLogger("c2farm")

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
        fabric=dataclasses.replace(config.fabric, identity=identity(role, instance)),
    )
    stop_on_signals(ctx.stop)
    if os.environ.get(PARENT_ENV):
        watch_parent(int(os.environ[PARENT_ENV]), ctx.stop)
    if role != "router" and not wait_for_listener(config.fabric.connect, config.launch.router_wait_s, ctx.stop):
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
    if args.command == "certs":
        return make_certs_command(args)
    if args.command in ("export", "import"):
        return interchange_command(args)
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
            from deploy.robot_demos import run as record_robot_demos

            return record_robot_demos(args, config)
        if getattr(args, "policy", None):  # eval / robot with an exported policy: joins no run
            from deploy.policy_eval import policy_command

            return policy_command(args, config)
        if config.run.run_id is None:
            raise ConfigError(
                "run.run_id: not set; every role of a run needs the same --run-id (`c2farm launch` prints it)"
            )
    except ConfigError as exc:
        print(f"c2farm: config error: {exc}", file=sys.stderr)
        return 2
    from deploy.preflight import problems

    if args.command == "launch":
        found = problems(config, list(config.launch.roles))
    else:
        found = problems(config, [args.command], instance=args.instance)
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


def interchange_command(args) -> int:
    """``c2farm export policy|lerobot`` and ``c2farm import lerobot``."""
    if (args.command, args.what) == ("export", "policy"):
        from deploy.policy_export import export_command

        return export_command(args)
    from deploy import lerobot_dataset

    return (lerobot_dataset.export_command if args.command == "export" else lerobot_dataset.import_command)(args)


def make_certs_command(args) -> int:
    """``c2farm certs DIR``: what is missing, made; one line per problem otherwise."""
    from deploy.certs import CertsPlan, make_certs, role_of
    from deploy.roles import ROLES
    from protocol import keys

    bad = [n for n in args.identity
           if role_of(n) not in ROLES or "." not in n or not keys.is_valid_id(n.split(".", 1)[1])]
    if bad or args.actors < 0 or args.days < 1:
        what = f"--identity {bad[0]!r}: expected ROLE.INSTANCE with a role of {', '.join(ROLES)}" if bad else \
            "--actors must be >= 0 and --days >= 1"
        print(f"c2farm: certs: {what}", file=sys.stderr)
        return 2
    plan = CertsPlan(Path(args.directory), hubs=list(args.hub), actors=args.actors,
                     instance_prefix=args.instance_prefix, extra=list(args.identity), days=args.days)
    written = make_certs(plan)
    print(f"c2farm certs: {len(written)} new files in {plan.directory} ({len(plan.identities())} identities); "
          f"start every role with --certs {plan.directory}")
    return 0


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
