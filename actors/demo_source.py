"""Demonstrations into the replay: a demo source is just another actor.

Each demo file becomes keyframe-to-keyframe episodes (the operator's keyframes, or keyframe
discovery, + demo augmentation, as the authors' ARM code does), published through the same outbox and protocol as
live episodes, flagged ``is_demo``. Episode ids are derived from the file order, so running
the source again (after a crash or a replay restart) stores nothing twice.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from actors.config import ActorConfig
from actors.demos.augmentation import demo_to_transitions
from actors.demos.keyframes import demo_keyframes
from actors.sim.task_specs import task_spec
from protocol.episode import Episode, stack_observations
from protocol.episode_file import load_demo
from protocol.episode_outbox import Outbox
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext
from protocol.transition import pad_act_labels, stamp_scene_bounds

log = logging.getLogger("demos")

#: Room for augmented episodes per demo in the episode-id space.
IDS_PER_DEMO = 10_000


def demo_episodes(path: Path, demo_index: int, actor_id: str, every_n: int = 10, depths: int = 2,
                  scene_bounds_on_wire: bool = False, chain_keyframes: int = 0) -> list[Episode]:
    """The demo-augmented episodes of one demo file, ready to publish.

    ``depths`` sizes the (unused, zero) act-time label arrays that live episodes carry. With
    ``scene_bounds_on_wire`` every observation carries the demo's depth-0 box: the one a robot
    demo was recorded for, else its simulated task's. ``chain_keyframes`` cuts the augmented chains
    (``demo_to_transitions``); a cut one is not a success.
    """
    demo = load_demo(path)
    if scene_bounds_on_wire:
        stamp_scene_bounds(demo.observations, demo.scene_bounds or task_bounds(demo.task))
    keyframes = demo_keyframes(demo)  # the operator's (robot demos) or discovered
    episodes = []
    parts = demo_to_transitions(demo.observations, keyframes, every_n=every_n, chain_keyframes=chain_keyframes)
    for i, part in enumerate(parts):
        steps = len(part.actions)
        pad_act_labels(part.observations, depths)
        episodes.append(Episode(
            actor_id=actor_id,
            episode_id=demo_index * IDS_PER_DEMO + i,
            task=demo.task,
            seed=demo.seed,
            is_demo=True,
            success=bool(part.terminals[-1]),
            timeout=False,
            observations=stack_observations(part.observations),
            actions=np.asarray(part.actions, dtype=np.float32),
            rewards=np.asarray(part.rewards, dtype=np.float32),
            terminals=np.asarray(part.terminals, dtype=bool),
            policy_versions=np.full(steps, -1, dtype=np.int64),
            info={"demo_file": path.name},
        ))
    return episodes


def task_bounds(task: str) -> tuple[float, ...]:
    """The depth-0 box of a simulated task."""
    return tuple(task_spec(task).scene_bounds)


@dataclass
class DemoSourceSetup:
    """What the demo source role is told (``run(setup, ctx)``)."""

    directory: Path  #: the demo files (*.mcap) to publish
    actor: ActorConfig  #: outbox settings, and whether episodes carry their depth-0 box
    every_n: int = 10  #: demo augmentation: an episode from every n-th frame to its next keyframe
    limit: int = 0  #: publish only the first ``limit`` demos (0: all)
    depths: int = 2  #: the cascade's depths, for the act-time labels of each keyframe
    chain_keyframes: int = 0  #: demo augmentation: keyframes per augmented episode but frame 0's (0: all)


def run(setup: DemoSourceSetup, ctx: RoleContext) -> int:
    """Publish every demo in ``setup.directory`` (the first ``limit`` if set) and wait for the acks."""
    config, every_n, depths, chain = setup.actor, setup.every_n, setup.depths, setup.chain_keyframes
    demo_dir = setup.directory
    files = sorted(Path(demo_dir).glob("*.mcap"))[: setup.limit or None]
    if not files:
        log.error("no demo files (*.mcap) in %s", demo_dir)
        return 1
    session = open_session(ctx.fabric)
    outbox = Outbox(session, ctx.run_id, ctx.instance, config.outbox_size, config.resend_after_s,
                    config.outbox_wait_s, stop=ctx.stop)
    published = {"demos": 0, "demo_episodes": 0}
    heartbeat = Heartbeat(session, ctx.run_id, "demos", ctx.instance,
                          counters=lambda: {**published, **outbox.counters, "outbox_pending": outbox.pending})
    try:
        for index, path in enumerate(files):
            if ctx.stop.is_set():
                break
            for episode in demo_episodes(path, index, ctx.instance, every_n, depths, config.scene_bounds_on_wire,
                                         chain):
                outbox.send(episode)
                published["demo_episodes"] += 1
            published["demos"] += 1
        flushed = outbox.flush(timeout_s=120.0, stop=ctx.stop)
        log.info("published %d demo episodes from %d demos (%s)", published["demo_episodes"],
                 published["demos"], "all acknowledged" if flushed else f"{outbox.pending} unacknowledged")
        return 0 if flushed else 1
    finally:
        heartbeat.close()
        outbox.close()
        session.close()
