"""TD targets and losses of one update (spec §5), kept free of optimiser state.

Per depth: double-DQN target (online argmax on s_t+1, target-net value), at the last depth the
mean over translation, 3 rotation axes and gripper; y = max(r*scale + gamma*(1-terminal)*q', 0);
Huber TD per head, averaged (at the last depth the translation head's share is
``last_translation_td``, 1/5 in the reference); L1 Q-regulariser over all outputs;
importance-weighted mean.
Optional (not in the reference): DQfD's large-margin loss on demo rows (``demo_margin`` > 0).
Deviation: the s_t+1 cube of depth d>=1 is centred on the online net's greedy depth d-1 choice
at s_t+1 (the cascade's own max), not on a coordinate stored with the next observation.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from .cascade import split_rot_grip
from .voxelise import child_bounds, flat_index, unflatten_index, voxel_centre


def bootstrap_value(q_online, rg_online, q_target, rg_target, bins: int):
    """Double-DQN value [B] plus the online argmax voxel [B, 3] of one depth."""
    b, v = q_online.shape[0], q_online.shape[1]
    a = q_online.reshape(b, -1).argmax(1)
    values = [q_target.reshape(b, -1).gather(1, a[:, None])[:, 0]]
    if rg_online is not None:
        rot_on, grip_on = split_rot_grip(rg_online, bins)
        rot_tg, grip_tg = split_rot_grip(rg_target, bins)
        values += list(rot_tg.gather(2, rot_on.argmax(2, keepdim=True))[..., 0].unbind(1))
        values.append(grip_tg.gather(1, grip_on.argmax(1, keepdim=True))[:, 0])
    return torch.stack(values, 1).float().mean(1), unflatten_index(a, v)


def td_target(reward, terminal, q_next, config, n_rewards=None, bootstrap_steps=None) -> torch.Tensor:
    """y = max(r * reward_scale (negatives zeroed) + gamma * (1 - terminal) * q_next, 0).

    For n-step transitions (``n_rewards`` [B, n], ``bootstrap_steps`` m [B]) the reward is the
    discounted sum of the n rewards (each scaled and floored at 0, zeros past the transition's
    end) and the bootstrap is discounted by gamma ** m: a demo's first keyframe sees the task's
    reward at once instead of after the target networks have carried it back one step at a time.
    """
    if n_rewards is None:
        r = (reward * config.reward_scale).clamp_min(0.0)
        discount = torch.full_like(r, config.gamma)
    else:
        powers = config.gamma ** torch.arange(n_rewards.shape[1], device=n_rewards.device, dtype=torch.float32)
        r = ((n_rewards * config.reward_scale).clamp_min(0.0) * powers).sum(1)
        discount = config.gamma ** bootstrap_steps.float()
    return (r + discount * (~terminal).float() * q_next).clamp_min(0.0)


@dataclass
class DepthLoss:
    loss: torch.Tensor  #: scalar to minimise
    delta: torch.Tensor  #: [B] mean Huber TD error over heads (detached), for priorities
    qreg: torch.Tensor  #: [B] Q regulariser (detached)
    q_chosen: torch.Tensor  #: [B] online translation Q at the label (detached)
    td_heads: torch.Tensor  #: [B, heads] Huber TD per head (detached)
    margin: torch.Tensor  #: [B] demo margin loss, 0 on agent rows or when off (detached)


def margin_loss(q: torch.Tensor, label: torch.Tensor, margin: float) -> torch.Tensor:
    """DQfD's supervised loss [B] for one head: ``max_a (Q(a) + margin * [a != label]) - Q(label)``.

    Zero once the labelled choice beats every other by ``margin``; unlike cross-entropy it
    leaves the Q-values' scale to the TD loss, so demos teach the ranking, not the values.
    """
    chosen = q.gather(1, label[:, None])[:, 0]
    lifted = q + margin
    lifted = lifted.scatter(1, label[:, None], chosen[:, None])
    return lifted.max(1).values - chosen


def depth_loss(q_trans, q_rg, voxel_index, rot_grip, y, weights, config, is_demo=None) -> DepthLoss:
    """Loss of one depth given its online outputs and labels (voxel [B, 3], rot_grip [B, 4]).

    With ``config.demo_margin`` > 0, rows flagged in ``is_demo`` [B] also pay the margin loss of
    every head (at the last depth each head's times ``last_head_margin``, 1/5 = their mean; all
    times ``lambda_demo_margin``); priorities stay TD-only.
    """
    b, v = q_trans.shape[0], config.voxel_size
    q_flat = q_trans.reshape(b, -1).float()
    label = flat_index(voxel_index, v)
    chosen = q_flat.gather(1, label[:, None])[:, 0]
    td = [F.smooth_l1_loss(chosen, y, reduction="none")]
    qreg = config.lambda_trans_qreg * q_flat.abs().mean(1)
    heads = [(q_flat, label)]
    if q_rg is not None:
        q_rg = q_rg.float()
        rot, grip = split_rot_grip(q_rg, config.rotation_bins)
        rot_chosen = rot.gather(2, rot_grip[:, :3, None])[..., 0]
        td += [F.smooth_l1_loss(rot_chosen[:, i], y, reduction="none") for i in range(3)]
        td.append(F.smooth_l1_loss(grip.gather(1, rot_grip[:, 3:4])[:, 0], y, reduction="none"))
        qreg = qreg + config.lambda_rot_qreg * q_rg.abs().mean(1)
        heads += [(rot[:, i], rot_grip[:, i]) for i in range(3)] + [(grip, rot_grip[:, 3])]
    td = torch.stack(td, 1)
    if q_rg is None:
        delta = td[:, 0]
    else:  # the reference's mean of five heads, with the translation head's share configurable
        delta = config.last_translation_td * td[:, 0] + td[:, 1:].sum(1) / 5
    margin = torch.zeros_like(delta)
    if config.demo_margin > 0 and is_demo is not None and bool(is_demo.any()):
        per_head = torch.stack([margin_loss(q, a, config.demo_margin) for q, a in heads], 1)
        # at the last depth the mean of five, scaled so the default 0.2 each leaves it exactly the mean
        per_row = per_head[:, 0] if q_rg is None else per_head.mean(1) * (5 * config.last_head_margin)
        margin = per_row * is_demo.float()
    loss = ((delta + qreg + config.lambda_demo_margin * margin) * weights).mean()
    return DepthLoss(loss, delta.detach(), qreg.detach(), chosen.detach(), td.detach(), margin.detach())


def priorities(deltas: list[torch.Tensor], alpha: float) -> torch.Tensor:
    """Per-sample priority, PER alpha applied: ``mean_d(sqrt(delta_d) / max_batch sqrt(delta_d)) ** alpha``.

    Each depth's term is batch-normalised as in the reference, but depths are combined once
    (the reference counted depth 0 twice, spec §10.7); the mean keeps priorities in (0, 1].
    Always finite: a row whose TD error is non-finite at any depth gets 0 (the replay floors it
    at its epsilon, so a poisoned transition is rarely drawn again) and is left out of the
    batch maxima, so it cannot spoil the other rows' priorities.
    """
    finite = torch.stack([torch.isfinite(d) for d in deltas], 0).all(0)
    terms = []
    for delta in deltas:
        p = torch.sqrt(torch.where(finite, delta, 0.0).clamp_min(0.0) + 1e-10)
        terms.append(p / p.max())
    return torch.where(finite, torch.stack(terms, 0).mean(0) ** alpha, 0.0)


def next_bounds(index: torch.Tensor, bounds: torch.Tensor, config, depth: int) -> torch.Tensor:
    """Bounds of depth ``depth + 1`` around the centre of ``index`` in ``bounds``."""
    return child_bounds(voxel_centre(index, bounds, config.voxel_size), config.offset(depth + 1))
