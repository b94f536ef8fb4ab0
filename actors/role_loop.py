"""What every acting role (actor, evaluator, robot actor) sets up around its loop, once.

Each of them is a loop of episodes between the same four links to the run: a Zenoh session,
a weights follower (the learner's newest networks), an episode outbox (at-least-once delivery
to the replay; the evaluator sends none) and a heartbeat (its counters for the dashboard).
:class:`RoleLinks` opens them in the order they depend on each other and closes them in
reverse, whatever ends the loop; :class:`EpisodeStats` counts episodes the same way for the
actor and the robot actor.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from actors.config import ActorConfig
from actors.sim.config import SimConfig
from protocol.episode_outbox import Outbox
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.role import RoleContext
from protocol.weights_follower import WeightsFollower
from qattention.config import QAttentionConfig
from qattention.digest import network_digest

if TYPE_CHECKING:
    from actors.actor_loop import Rollout


@dataclass
class ActingSetup:
    """What the actor and the evaluator roles are told (``run(setup, ctx)``): three sections of the run config."""

    actor: ActorConfig  #: acting, exploration, outbox and evaluation settings
    sim: SimConfig  #: the simulated task, cameras and control agent
    network: QAttentionConfig  #: the Q-attention cascade, as the learner trains it


class RoleLinks:
    """A role's session, weights follower, optional outbox and heartbeat; a context manager closing all four.

    The heartbeat starts last (:meth:`beat`), once whatever its counters read exists.
    """

    def __init__(self, ctx: RoleContext, network: QAttentionConfig, sends: ActorConfig | None = None) -> None:
        """``sends``: the outbox settings of a role that sends episodes (None: it sends none)."""
        self.ctx = ctx
        self.session = open_session(ctx.fabric)
        self.follower: WeightsFollower | None = None
        self.outbox: Outbox | None = None
        self.heartbeat: Heartbeat | None = None
        try:
            self.follower = WeightsFollower(self.session, ctx.run_id, network_digest(network))
            if sends is not None:
                self.outbox = Outbox(self.session, ctx.run_id, ctx.instance, sends.outbox_size, sends.resend_after_s,
                                     sends.outbox_wait_s, stop=ctx.stop)
        except BaseException:
            self.close()
            raise

    def beat(self, role: str, counters: Callable[[], dict[str, float]], info: Callable[[], dict]) -> Heartbeat:
        """Start publishing this role's status (``counters`` and ``info`` are called from the heartbeat's thread)."""
        self.heartbeat = Heartbeat(self.session, self.ctx.run_id, role, self.ctx.instance, counters=counters, info=info)
        return self.heartbeat

    def close(self) -> None:
        for part in (self.heartbeat, self.outbox, self.follower, self.session):
            if part is not None:
                part.close()

    def __enter__(self) -> RoleLinks:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def first_episode_id() -> int:
    """Episode ids must grow across restarts of an actor, or the replay would drop new episodes as
    duplicates: start from the clock in milliseconds (an episode takes far longer than 1 ms)."""
    return int(time.time() * 1000)


@dataclass
class EpisodeStats:
    """Counts over the episodes a role collected, for its heartbeat."""

    counts: dict[str, float] = field(default_factory=lambda: {
        "episodes": 0, "env_steps": 0, "successes": 0, "unreachable": 0, "timeouts": 0, "reach_checks": 0,
        "reach_replaced": 0, "repeats_skipped": 0})

    def add(self, rollout: Rollout) -> None:
        """Count one finished ``actors.actor_loop.Rollout``."""
        c = self.counts
        c["episodes"] += 1
        c["env_steps"] += len(rollout.actions)
        c["successes"] += int(rollout.success)
        c["timeouts"] += int(rollout.timeout)
        c["unreachable"] += int(rollout.reason == "unreachable")
        if rollout.unreachable_reason:  # one counter per reason the control agent or the arm gave
            key = f"unreachable_{rollout.unreachable_reason}"
            c[key] = c.get(key, 0) + 1
        c["reach_checks"] += rollout.reach_checks
        c["reach_replaced"] += rollout.reach_replaced
        c["repeats_skipped"] += rollout.repeats_skipped

    def as_dict(self) -> dict[str, float]:
        episodes = max(1, self.counts["episodes"])
        return {**self.counts, "success_rate": self.counts["successes"] / episodes,
                "unreachable_rate": self.counts["unreachable"] / episodes}
