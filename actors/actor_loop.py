"""An actor: one task environment plus the Q-attention cascade on one CPU core.

Acts with the newest weights (swapped in between episodes, never mid-episode, so every
episode has one policy version), executes each next-best pose through the control agent,
and hands finished episodes to the outbox, which delivers them at least once.
"""

from __future__ import annotations

import contextlib
import logging
import time
import zlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from actors.environment import Env
from actors.role_loop import ActingSetup, EpisodeStats, RoleLinks, first_episode_id
from protocol.episode import Episode, stack_observations
from protocol.messages import WeightsUpdate
from protocol.observation import Observation
from protocol.role import RoleContext
from protocol.transition import pad_act_labels, stamp_scene_bounds
from protocol.weights_follower import WeightsFollower
from qattention.agent import C2FARM
from qattention.batch import ObservationBatch
from qattention.cascade import ActResult
from qattention.config import QAttentionConfig

log = logging.getLogger("actor")


@dataclass
class Rollout:
    """What one episode produced, before it becomes a wire ``Episode``."""

    observations: list[Observation]
    actions: list[np.ndarray] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    terminals: list[bool] = field(default_factory=list)
    success: bool = False
    timeout: bool = False
    reason: str = ""  #: why it ended: success, timeout, unreachable or failed
    unreachable_reason: str = ""  #: the control agent's why, for an unreachable end (UNREACHABLE_REASONS)
    reach_checks: int = 0  #: reachability tests run while acting (reachable_top_k)
    reach_replaced: int = 0  #: decisions whose first choice was unreachable and a reachable candidate took over
    repeats_skipped: int = 0  #: decisions whose choice repeated the gripper's pose and one that moves took over

    @property
    def total_reward(self) -> float:
        return float(sum(self.rewards))


def rollout(env: Env, agent: C2FARM, cameras, seed: int, explore: bool, stop=None, top_k: int = 0,
            on_decision: Callable[[Observation, ActResult], None] | None = None,
            skip_repeats: bool = False) -> Rollout | None:
    """Play one episode: observe, choose a next-best pose, let the control agent execute it.

    ``top_k`` > 1 lets an unreachable choice give way to the best reachable one of the top-K;
    ``skip_repeats``, a choice that repeats the gripper's pose to the best one that moves.
    ``on_decision`` sees each observation with the cascade's decision on it before the arm
    moves (the live view draws the attention). Returns None when ``stop`` is set mid-episode
    (a cut-short episode is not data).
    """
    obs = env.reset(seed=seed)
    result = Rollout(observations=[obs])
    reachable = env.reachable if top_k > 1 else None
    for _ in range(env.episode_length):
        if stop is not None and stop.is_set():
            return None
        act = agent.act(ObservationBatch.from_observations([obs], cameras, agent.device), explore=explore,
                        reachable=reachable, top_k=top_k, skip_repeats=skip_repeats)
        if on_decision is not None:
            on_decision(obs, act)
        if act.reach_checks is not None:
            result.reach_checks += int(act.reach_checks[0])
            result.reach_replaced += int(act.reach_replaced[0])
        if act.repeat_skipped is not None:
            result.repeats_skipped += int(act.repeat_skipped[0])
        action = np.asarray(act.action[0], dtype=np.float32)
        # The labels actually chosen (per-depth voxels, cube centres, bins) travel with the
        # observation: re-encoding the continuous pose would not always give them back.
        obs.extras.update({name: np.asarray(v[0]) for name, v in act.replay_elements().items()})
        step = env.step(action)
        obs = step.observation
        result.observations.append(obs)
        result.actions.append(action)
        result.rewards.append(float(step.reward))
        result.terminals.append(bool(step.terminal))
        if step.terminal:
            pad_act_labels(result.observations, agent.config.depths)
            result.success = bool(step.success)
            result.reason = "success" if step.success else ("unreachable" if step.unreachable else "failed")
            result.unreachable_reason = step.info.get("reason", "") if step.unreachable else ""
            return result
    pad_act_labels(result.observations, agent.config.depths)
    # Out of decisions: the authors' code treats a timeout as terminal too (no bootstrapping past it).
    result.terminals[-1] = True
    result.timeout, result.reason = True, "timeout"
    return result


def to_episode(r: Rollout, actor_id: str, episode_id: int, task: str, seed: int, version: int) -> Episode:
    steps = len(r.actions)
    return Episode(
        actor_id=actor_id,
        episode_id=episode_id,
        task=task,
        seed=seed,
        is_demo=False,
        success=r.success,
        timeout=r.timeout,
        observations=stack_observations(r.observations),
        actions=np.stack(r.actions).astype(np.float32),
        rewards=np.asarray(r.rewards, dtype=np.float32),
        terminals=np.asarray(r.terminals, dtype=bool),
        policy_versions=np.full(steps, version, dtype=np.int64),
        info={"end": r.reason, **({"unreachable": r.unreachable_reason} if r.unreachable_reason else {})},
    )


def episode_seed(base_seed: int, instance: str, episode_id: int) -> int:
    """A per-episode environment seed, reproducible from (run seed, actor, episode id)."""
    return int(np.random.SeedSequence([base_seed, zlib.crc32(instance.encode()), episode_id]).generate_state(1)[0])


class ActingPolicy:
    """The cascade plus the weights it currently runs, swapped only when asked.

    ``epsilon``, when given, maps the running weights' learner step to the exploration
    probability (ActorConfig.epsilon_at); without it qconfig's epsilon stays.
    """

    def __init__(self, qconfig: QAttentionConfig, follower: WeightsFollower,
                 epsilon: Callable[[int], float] | None = None):
        self.agent = C2FARM(qconfig, device=torch.device("cpu"))
        self.follower = follower
        self.epsilon = epsilon
        self.swaps = 0
        self.adopted: WeightsUpdate | None = None  #: the update now running (its steps label an evaluation)

    @property
    def version(self) -> int:
        return self.follower.version

    def refresh(self) -> bool:
        """Swap in the newest received weights, if any; True when the policy changed."""
        update = self.follower.newer()
        if update is None or not self.follower.adopt(update, self.agent.load_weights):
            return False  # nothing new, or it did not fit the networks (counted; the old weights stay)
        self.swaps += 1
        self.adopted = update
        if self.epsilon is not None:
            self.agent.config = self.agent.config.replace(epsilon=self.epsilon(update.learner_step))
        return True

    def wait_for_first(self, timeout_s: float, stop) -> None:
        deadline = time.monotonic() + timeout_s
        while not stop.is_set() and time.monotonic() < deadline:
            self.follower.fetch_latest(timeout_s=2.0)
            if self.refresh():
                return
            stop.wait(0.5)
        if self.version == 0:
            log.warning("no weights after %.0f s: acting with the initial random network", timeout_s)


def run(setup: ActingSetup, ctx: RoleContext) -> int:
    """Collect episodes until stopped (or ``max_episodes``)."""
    from actors.panda_env import PandaEnv  # the heavy simulator import stays out of the module's import

    config, sim_config = setup.actor, setup.sim
    torch.set_num_threads(max(1, config.torch_threads))
    torch.manual_seed(ctx.seed + zlib.crc32(ctx.instance.encode()))
    qconfig = setup.network.replace(epsilon=config.epsilon)
    stats = EpisodeStats()
    first_id = first_episode_id()
    with contextlib.closing(PandaEnv(sim_config)) as env, RoleLinks(ctx, qconfig, sends=config) as links:
        follower, outbox = links.follower, links.outbox
        policy = ActingPolicy(qconfig, follower, epsilon=config.epsilon_at)

        def counters() -> dict[str, float]:
            return {**stats.as_dict(), **outbox.counters, "outbox_pending": outbox.pending,
                    "weights_version": policy.version, "epsilon": policy.agent.config.epsilon,
                    **follower.counters(), "weights_latency_s": follower.latency_s}

        links.beat("actor", counters, info=lambda: {"task": sim_config.task})
        policy.wait_for_first(config.weights_wait_s, ctx.stop)
        n = 0
        while not ctx.stop.is_set() and not (config.max_episodes and n >= config.max_episodes):
            policy.refresh()
            episode_id = first_id + n
            seed = episode_seed(ctx.seed, ctx.instance, episode_id)
            r = rollout(env, policy.agent, qconfig.cameras, seed, explore=True, stop=ctx.stop,
                        **config.acting_rules())
            if r is None:
                break
            if config.scene_bounds_on_wire:
                stamp_scene_bounds(r.observations, env.scene_bounds)
            outbox.send(to_episode(r, ctx.instance, episode_id, sim_config.task, seed, policy.version))
            outbox.resend_due()
            n += 1
            stats.add(r)
        # inside the launcher's grace period; what is still unacknowledged after this is lost
        outbox.flush(timeout_s=2.0)
    return 0
