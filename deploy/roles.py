"""Each role's entry point, fed the sections of the one run config it needs.

Roles never import each other; this module is where they meet the config. Heavy imports
(torch, PyBullet) stay inside the functions, so starting the router or the dashboard does
not pay for them.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import tempfile
from pathlib import Path
from typing import Callable

from actors.sim.task_specs import task_spec
from deploy.config import DEFAULT_INSTANCE, RunConfig
from protocol.role import RoleContext

log = logging.getLogger("c2farm")


def network_config(config: RunConfig):
    """The Q-attention config with the task-dependent keys derived from ``sim``.

    Cameras, episode length and the depth-0 scene bounds always come from the simulator
    section and the task's spec (read without pybullet, so the learner does not load it), so
    actors, evaluators and the learner cannot disagree on them.
    """
    task = task_spec(config.sim.task)
    return config.qattention.replace(
        cameras=tuple(config.sim.cameras),
        episode_length=config.sim.episode_length or task.episode_length,
        scene_bounds=tuple(float(b) for b in task.scene_bounds),
    )


def demo_dir(config: RunConfig) -> Path:
    """Demos are shared between runs of the same task (and its revision), cameras and image size."""
    sim = config.sim
    revision = task_spec(sim.task).revision
    name = f"{sim.task}{f'-r{revision}' if revision > 1 else ''}-{'+'.join(sim.cameras)}-{sim.image_size}px"
    return Path(config.demos.directory) / name


def router(config: RunConfig, ctx: RoleContext) -> int:
    from deploy.router import run

    return run(ctx.fabric, ctx)  # ctx's: it carries this process's identity


def curve_files(config: RunConfig) -> dict[str, dict[str, str]]:
    """The CURVE key files ``c2farm certs`` made (``fabric.certs``), for the replay and the learner
    sections whose own CURVE fields are unset; {} when the fabric has no keys."""
    if not config.fabric.certs:
        return {}
    curve = Path(config.fabric.certs) / "curve"
    out: dict[str, dict[str, str]] = {}
    if not config.replay.curve_certificate:
        out["replay"] = {"curve_certificate": str(curve / "replay.key_secret"), "curve_clients": str(curve / "clients")}
    if not config.learner.curve_certificate:
        out["learner"] = {"curve_certificate": str(curve / "learner.key_secret"),
                          "curve_server_key": str(curve / "replay.key")}
    return out


def replay(config: RunConfig, ctx: RoleContext) -> int:
    from replay_server.service import run

    return run(dataclasses.replace(config.replay, **curve_files(config).get("replay", {})), ctx)


def learner(config: RunConfig, ctx: RoleContext) -> int:
    from learner.train import LearnerSetup, run

    settings = dataclasses.replace(config.learner, **curve_files(config).get("learner", {}))
    if not settings.replay_endpoint:  # same host as the replay: dial what it binds
        endpoint = config.replay.zmq_endpoint.replace("://*:", "://127.0.0.1:").replace("://0.0.0.0:", "://127.0.0.1:")
        settings = dataclasses.replace(settings, replay_endpoint=endpoint)
    return run(LearnerSetup(settings, network_config(config)), ctx)


def actor(config: RunConfig, ctx: RoleContext) -> int:
    from actors.actor_loop import run
    from actors.role_loop import ActingSetup

    return run(ActingSetup(config.actor, config.sim, network_config(config)), ctx)


def evaluator(config: RunConfig, ctx: RoleContext) -> int:
    from actors.evaluation import run
    from actors.role_loop import ActingSetup

    return run(ActingSetup(config.actor, config.sim, network_config(config)), ctx)


def demo_source(config: RunConfig, ctx: RoleContext) -> int:
    """Generate the run's demos if they are missing, then publish them to the replay."""
    from actors.demo_source import DemoSourceSetup, run
    from actors.demos.generate import generate_demos

    directory = demo_dir(config)
    have = len(list(directory.glob("*.mcap"))) if directory.is_dir() else 0
    if have < config.demos.episodes:
        log.info("generating %d demos of %s in %s", config.demos.episodes, config.sim.task, directory)
        # Written aside and moved in only when complete: a demo source killed mid-write must
        # not leave a truncated file that every later start would count as a demo.
        directory.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix=".partial-", dir=directory.parent) as partial:
            generate_demos(config.sim.task, config.demos.episodes, seed=config.demos.seed, out_dir=partial,
                           cameras=tuple(config.sim.cameras), image_size=config.sim.image_size, progress=False)
            directory.mkdir(parents=True, exist_ok=True)
            for path in sorted(Path(partial).glob("*.mcap")):
                os.replace(path, directory / path.name)
    return run(DemoSourceSetup(directory, config.actor, every_n=config.demos.every_n, limit=config.demos.episodes,
                               depths=config.qattention.depths, chain_keyframes=config.demos.chain_keyframes), ctx)


def robot(config: RunConfig, ctx: RoleContext) -> int:
    from actors.robot.actor import RobotSetup, run, terminal_stream

    return run(RobotSetup(config.actor, config.robot, config.sim.task, network_config(config), terminal_stream()), ctx)


def dashboard(config: RunConfig, ctx: RoleContext) -> int:
    from dashboard.service import run

    return run(config.dashboard, ctx)


#: role -> (entry point, default instance name)
ROLES: dict[str, tuple[Callable[[RunConfig, RoleContext], int], str]] = {
    role: (entry, DEFAULT_INSTANCE[role])
    for role, entry in (
        ("router", router),
        ("replay", replay),
        ("learner", learner),
        ("actor", actor),
        ("eval", evaluator),
        ("demo_source", demo_source),
        ("dashboard", dashboard),
        ("robot", robot),
    )
}
