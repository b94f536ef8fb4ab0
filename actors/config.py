"""Settings of an actor process (``c2farm actor``): acting, delivery and evaluation."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ActorConfig:
    """How an actor acts, delivers episodes and (as an evaluator) measures success."""

    epsilon: float = 0.1  #: exploration probability per depth / rotation axis / gripper on training actors
    epsilon_final: float = 0.02  #: epsilon once decayed (only with epsilon_decay_updates > 0)
    epsilon_decay_updates: int = 0  #: linearly anneal epsilon to epsilon_final over this many learner updates; 0 = constant
    reachable_top_k: int = 0  #: an unreachable choice gives way to the best reachable (IK test) of the top-K; 0 = off (reference)
    torch_threads: int = 1  #: intra-op threads for acting (one core per actor)
    outbox_size: int = 16  #: unacknowledged episodes kept for resending; a full outbox waits, then drops the oldest
    resend_after_s: float = 10.0  #: resend an episode not acknowledged within this time
    outbox_wait_s: float = 30.0  #: longest wait for room in a full outbox before dropping the oldest
    weights_wait_s: float = 60.0  #: at start, wait this long for the first weights (then act with random init)
    max_episodes: int = 0  #: stop after this many episodes; 0 = until stopped
    eval_episodes: int = 20  #: evaluator: seeded episodes per weights version
    eval_min_episodes: int = 10  #: evaluator: stop a version's evaluation after this many if none succeeded (0 % needs fewer)
    eval_seed: int = 1_000_000  #: evaluator: first seed of the fixed evaluation set (disjoint from training seeds)
    eval_every_versions: int = 5  #: evaluator: evaluate a version only if this many versions passed since the last
    record_eval: bool = True  #: evaluator: write each evaluation episode as MCAP under runs/<id>/eval/
    scene_bounds_on_wire: bool = False  #: every episode carries its depth-0 box (extra_scene_bounds); needed in a run with a robot actor, whose box is not the task's (the replay wants one set of arrays)
    eval_tensorboard: bool = True  #: evaluator: also write eval success, return and unreachable rate to TensorBoard (runs/<id>/tensorboard, beside the learner's scalars)

    def __post_init__(self) -> None:
        if self.eval_episodes < 1 or self.eval_min_episodes < 1:
            raise ValueError("eval_episodes and eval_min_episodes must be >= 1")
        if not (0.0 <= self.epsilon <= 1.0 and 0.0 <= self.epsilon_final <= 1.0):
            raise ValueError("epsilon and epsilon_final must be in [0, 1]")
        if self.epsilon_decay_updates < 0:
            raise ValueError("epsilon_decay_updates must be >= 0 (0 = constant epsilon)")
        if self.reachable_top_k < 0:
            raise ValueError("reachable_top_k must be >= 0 (0 = off)")

    def epsilon_at(self, learner_step: int) -> float:
        """Exploration probability when acting with weights from this learner step (DQN's linear anneal).

        Keyed to the learner's step, which every weights update carries, rather than to the
        actor's own episodes, so all actors, and one restarted mid-run, agree.
        """
        if self.epsilon_decay_updates <= 0:
            return self.epsilon
        done = min(1.0, max(0, learner_step) / self.epsilon_decay_updates)
        return self.epsilon + (self.epsilon_final - self.epsilon) * done
