"""Acting with an exported policy (``c2farm eval --policy``): weights from a file, not from a run.

The evaluator's own greedy episodes (``actors.evaluation.evaluate``, the same seeds) with a
fixed policy in place of the weights follower, so an exported policy scores as the run's
evaluator scored it, with no router, replay or learner anywhere.
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass

import torch

from actors.config import ActorConfig
from actors.evaluation import evaluate, live_view, watched
from actors.sim.config import SimConfig
from protocol.policy_file import PolicyFile, PolicyFileError
from qattention.agent import C2FARM
from qattention.config import QAttentionConfig
from qattention.digest import network_digest


@dataclass
class FixedPolicy:
    """What ``evaluate`` asks of an ``ActingPolicy`` (its cascade and weights version); these weights never change."""

    agent: C2FARM
    version: int
    learner_step: int


@dataclass
class PolicyEvaluation:
    """The greedy episodes of one policy on one task."""

    task: str
    episodes: int
    successes: int
    mean_return: float
    unreachable_rate: float
    version: int
    learner_step: int

    def line(self) -> str:
        """The one line ``c2farm eval --policy`` prints: the rate always with the count it rests on."""
        percent = 100 * self.successes / max(1, self.episodes)
        return (f"success {self.successes}/{self.episodes} ({percent:.0f} %) over {self.episodes} "
                f"episode{'s' if self.episodes != 1 else ''} of "
                f"{self.task}, policy v{self.version} (learner step {self.learner_step})")


def network_of(policy: PolicyFile) -> QAttentionConfig:
    """The cascade the policy's weights belong to; its config must match the digest it was exported with."""
    try:
        qconfig = QAttentionConfig.from_dict(policy.config["qattention"])
    except (TypeError, ValueError) as exc:
        raise PolicyFileError(f"config.json: qattention: {exc}") from None
    if network_digest(qconfig) != policy.config["network_digest"]:
        raise PolicyFileError(f"config.json: the qattention config's digest {network_digest(qconfig)} is not the "
                              f"network_digest {policy.config['network_digest']} the weights were exported with")
    return qconfig


def fixed_policy(policy: PolicyFile, qconfig: QAttentionConfig) -> FixedPolicy:
    """A greedy cascade running the policy's weights (names, shapes and finiteness checked)."""
    agent = C2FARM(qconfig.replace(epsilon=0.0), device=torch.device("cpu"))
    try:
        agent.load_weights(policy.tensors)
    except ValueError as exc:
        raise PolicyFileError(f"model.safetensors: {exc}") from None
    return FixedPolicy(agent, policy.version, policy.learner_step)


def result_of(outcome: tuple[float, float, float, int], task: str, policy: FixedPolicy) -> PolicyEvaluation:
    """``evaluate``'s (success rate, mean return, unreachable rate, episodes) as a :class:`PolicyEvaluation`."""
    success, mean_return, unreachable, n = outcome
    return PolicyEvaluation(task, n, round(success * n), mean_return, unreachable, policy.version,
                            policy.learner_step)


def evaluate_in_sim(policy: PolicyFile, sim: SimConfig, actor: ActorConfig,
                    stop: threading.Event) -> PolicyEvaluation | None:
    """``actor.eval_episodes`` greedy episodes of ``sim.task`` on seeds ``actor.eval_seed, ...``; None if stopped."""
    from actors.panda_env import PandaEnv

    qconfig = network_of(policy)
    fixed = fixed_policy(policy, qconfig)
    torch.set_num_threads(max(1, actor.torch_threads))
    with contextlib.closing(PandaEnv(sim)) as bare, live_view(actor.foxglove_port) as live:
        env, on_decision = watched(bare, live)
        outcome = evaluate(env, fixed, actor, qconfig.cameras, None, stop,
                           on_decision=on_decision)
    return None if outcome is None else result_of(outcome, sim.task, fixed)
