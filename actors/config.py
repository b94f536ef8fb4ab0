"""Settings of an actor process (``c2farm actor``): acting, delivery and evaluation."""

from __future__ import annotations

from dataclasses import dataclass

from protocol.config_checks import above, at_least, within


@dataclass
class ActorConfig:
    """How an actor acts, delivers episodes and (as an evaluator) measures success."""

    epsilon: float = 0.1  #: exploration probability per depth / rotation axis / gripper on training actors, in [0, 1]
    epsilon_final: float = 0.02  #: epsilon once decayed (only with epsilon_decay_updates > 0), in [0, 1]
    #: linearly anneal epsilon to epsilon_final over this many learner updates; 0 = constant
    epsilon_decay_updates: int = 0
    #: an unreachable choice gives way to the best reachable (IK test) of the top-K; 0 = off (reference)
    reachable_top_k: int = 0
    #: a choice that repeats the gripper's pose (its voxel, rotation bins and gripper state) gives way to the best one
    #: that moves; off = the reference (a greedy policy whose state does not change then repeats it to the end)
    skip_repeats: bool = False
    torch_threads: int = 1  #: intra-op threads for acting (one core per actor), >= 1
    #: unacknowledged episodes kept for resending, >= 1; a full outbox waits, then drops the oldest
    outbox_size: int = 16
    resend_after_s: float = 10.0  #: resend an episode not acknowledged within this time, seconds, > 0
    outbox_wait_s: float = 30.0  #: longest wait for room in a full outbox before dropping the oldest, seconds, >= 0
    #: at start, wait this long for the first weights (then act with random init), seconds, >= 0
    weights_wait_s: float = 60.0
    max_episodes: int = 0  #: stop after this many episodes; 0 = until stopped
    eval_episodes: int = 20  #: evaluator: seeded episodes per weights version, >= 1
    #: evaluator: stop a version's evaluation after this many if none succeeded (0 % needs fewer), >= 1
    eval_min_episodes: int = 10
    #: evaluator: first seed of the fixed evaluation set (disjoint from training seeds), >= 0
    eval_seed: int = 1_000_000
    #: evaluator: evaluate a version only if this many versions passed since the last, >= 1 (1 = every version)
    eval_every_versions: int = 5
    record_eval: bool = True  #: evaluator: write each evaluation episode as MCAP under runs/<id>/eval/
    #: evaluator and robot actor: serve the scene and each decision's attention live to Foxglove (WebSocket,
    #: loopback, subprotocol foxglove.sdk.v1) on this port; -1 = off, 0 = a free port (logged)
    foxglove_port: int = -1
    #: every episode carries its depth-0 box (extra_scene_bounds); needed in a run with a robot actor, whose box is not
    #: the task's (the replay wants one set of arrays)
    scene_bounds_on_wire: bool = False
    #: evaluator: also write eval success, return and unreachable rate to TensorBoard (runs/<id>/tensorboard, beside the
    #: learner's scalars)
    eval_tensorboard: bool = True

    def __post_init__(self) -> None:
        within(self, 0, 1, "epsilon", "epsilon_final")
        at_least(self, 0, "epsilon_decay_updates", "reachable_top_k", "max_episodes", "eval_seed", "outbox_wait_s",
                 "weights_wait_s")
        at_least(self, 1, "torch_threads", "outbox_size", "eval_episodes", "eval_min_episodes", "eval_every_versions")
        above(self, 0, "resend_after_s")
        if not -1 <= self.foxglove_port <= 65535:
            raise ValueError(f"foxglove_port must be -1 (off), 0 (a free port) or a port (got {self.foxglove_port})")

    def acting_rules(self) -> dict[str, int | bool]:
        """``rollout``'s keyword arguments for this config's acting rules: top-K reachability, skipping repeats."""
        return {"top_k": self.reachable_top_k, "skip_repeats": self.skip_repeats}

    def epsilon_at(self, learner_step: int) -> float:
        """Exploration probability when acting with weights from this learner step (DQN's linear anneal).

        Keyed to the learner's step, which every weights update carries, rather than to the
        actor's own episodes, so all actors, and one restarted mid-run, agree.
        """
        if self.epsilon_decay_updates <= 0:
            return self.epsilon
        done = min(1.0, max(0, learner_step) / self.epsilon_decay_updates)
        return self.epsilon + (self.epsilon_final - self.epsilon) * done
