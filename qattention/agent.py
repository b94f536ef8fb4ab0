"""C2F-ARM agent: the per-depth networks, their targets and optimisers; ``act`` and ``update``.

Used by actors (``act``, ``load_weights``) and the learner (``update``, ``state_dict``).
All state is tensors, so it saves with safetensors: ``state_dict()`` is a flat
``dict[str, Tensor]`` (online nets, target nets, Adam moments, update step, label RNG).
"""

from __future__ import annotations

import contextlib
import copy
import warnings

import numpy as np
import torch

from .action_codec import crop_noise, encode_action
from .batch import ObservationBatch, TransitionBatch
from .cascade import ActResult, depth_grid, descend
from .config import QAttentionConfig
from .loss import bootstrap_value, depth_loss, next_bounds, priorities, td_target
from .precision import native_bf16, use_bf16
from .q_attention import build_networks
from .reachability import ReachabilityTest
from .voxelise import child_bounds
from .yaw_augmentation import augment_yaw


class C2FARM:
    def __init__(self, config: QAttentionConfig, device: str | torch.device = "cpu", seed: int = 0):
        self.config = config
        self.device = torch.device(device)
        self.bf16 = use_bf16(config.bf16, self.device)  #: resolved for this device ("auto" -> native or not)
        if self.bf16 and not native_bf16(self.device):
            warnings.warn("bf16 autocast without native bf16 is emulated: 3D convs run 30-600x slower (BENCHMARKS.md)")
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            nets = build_networks(config)
        self.nets = torch.nn.ModuleList(nets).to(self.device)
        self.targets = copy.deepcopy(self.nets)
        self.targets.requires_grad_(False)
        self.optimisers = [
            torch.optim.Adam(n.parameters(), lr=config.lr, weight_decay=config.weight_decay) for n in self.nets
        ]
        self.generator = torch.Generator().manual_seed(seed)  # crop noise and exploration (CPU, then moved)
        self.update_step = 0  #: updates applied (skipped ones not counted)
        self.skipped_nonfinite = 0  #: updates skipped for a non-finite loss or gradient (this process only)

    # ------------------------------------------------------------------ acting
    def _autocast(self):
        if not self.bf16:
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=torch.bfloat16)

    def _q(self, net):
        def q(grid, proprio):
            with self._autocast():
                return net(grid, proprio)

        return q

    @torch.no_grad()
    def act(self, obs: ObservationBatch, explore: bool = False, reachable: ReachabilityTest | None = None,
            top_k: int = 0, skip_repeats: bool = False) -> ActResult:
        """Next-best pose for every observation of the batch (greedy unless ``explore`` and epsilon > 0).

        With ``reachable`` and ``top_k`` > 1, an unreachable choice gives way to the best reachable
        one of the top-K candidates (reachability.py); with ``skip_repeats``, a choice that repeats
        the gripper's pose gives way to the best one that moves (repeats.py).
        """
        self.nets.eval()
        return descend(obs, [self._q(n) for n in self.nets], self.config, explore, self.generator, reachable, top_k,
                       skip_repeats)

    # ---------------------------------------------------------------- learning
    def labels(self, batch: TransitionBatch):
        """Per-depth voxel labels, cube centres and bounds, rot/grip labels for a batch.

        Demo rows are labelled from ``action`` with fresh crop noise (new on every sample);
        agent rows use their act-time choices when the batch carries them, else ``action``.
        """
        cfg, b = self.config, batch.size
        scene = batch.obs.bounds(cfg.scene_bounds)
        noise = None
        if cfg.crop_augmentation and cfg.depths > 1:
            noise = crop_noise(b, cfg, self.generator).to(self.device) * batch.is_demo[:, None, None].float()
        lab = encode_action(batch.action, scene, cfg, noise)
        idx, coords, rot_grip = lab.voxel_indices, lab.coordinates, lab.rot_grip
        if batch.voxel_indices is not None and batch.attention_coordinates is not None:
            agent = ~batch.is_demo
            idx = torch.where(agent[:, None, None], batch.voxel_indices, idx)
            coords = torch.where(agent[:, None, None], batch.attention_coordinates, coords)
        if batch.rot_grip_indices is not None:
            rot_grip = torch.where((~batch.is_demo)[:, None], batch.rot_grip_indices, rot_grip)
        bounds = [scene] + [child_bounds(coords[:, d - 1], cfg.offset(d)) for d in range(1, cfg.depths)]
        return idx, coords, torch.stack(bounds, 1), rot_grip

    def update(self, batch: TransitionBatch) -> tuple[dict[str, float], np.ndarray]:
        """One gradient step per depth on the same batch; returns metrics and PER priorities [B].

        All or nothing: every depth's loss and gradients are computed first (the depths share
        no parameters, so this equals stepping them one after another). If any loss or any
        gradient is non-finite, no optimiser steps and no target net moves, for any depth: the
        update is skipped, counted (``metrics["skipped_nonfinite"] == 1`` and
        ``self.skipped_nonfinite``) and ``update_step`` does not advance. Metrics then carry no
        loss values (they would be NaN); priorities are always finite (``loss.priorities``).
        """
        cfg = self.config
        self.nets.train()
        batch = augment_yaw(batch, cfg.demo_yaw_augmentation, self.generator)
        idx, coords, bounds, rot_grip = self.labels(batch)

        # Targets first, from the networks as they are before this update.
        q_next = []
        with torch.no_grad():
            prop1 = batch.next_obs.proprioception(cfg)
            b1, centre = batch.next_obs.bounds(cfg.scene_bounds), None
            for d in range(cfg.depths):
                grid = depth_grid(batch.next_obs, cfg, centre, b1)
                with self._autocast():
                    q_on, rg_on = self.nets[d](grid, prop1)
                    q_tg, rg_tg = self.targets[d](grid, prop1)
                value, a = bootstrap_value(q_on, rg_on, q_tg, rg_tg, cfg.rotation_bins)
                q_next.append(value)
                if d < cfg.depths - 1:
                    b1 = next_bounds(a, b1, cfg, d)
                    centre = (b1[:, :3] + b1[:, 3:]) / 2

        prop = batch.obs.proprioception(cfg)
        outs, targets = [], []
        for d in range(cfg.depths):
            y = td_target(batch.reward, batch.terminal, q_next[d], cfg, batch.n_rewards, batch.bootstrap_steps)
            centre = coords[:, d - 1] if d > 0 else None
            grid = depth_grid(batch.obs, cfg, centre, bounds[:, d])
            with self._autocast():
                q, rg = self.nets[d](grid, prop)
            out = depth_loss(q, rg, idx[:, d], rot_grip, y, batch.weights, cfg, batch.is_demo)
            self.optimisers[d].zero_grad(set_to_none=True)
            out.loss.backward()
            outs.append(out)
            targets.append(y)
        prio = priorities([out.delta for out in outs], cfg.per_alpha).cpu().numpy().astype(np.float32)

        if not self._all_finite(outs):
            for opt in self.optimisers:
                opt.zero_grad(set_to_none=True)
            self.skipped_nonfinite += 1
            return {"skipped_nonfinite": 1.0, "update_step": float(self.update_step)}, prio

        metrics: dict[str, float] = {"skipped_nonfinite": 0.0}
        for d, (out, y) in enumerate(zip(outs, targets)):
            torch.nn.utils.clip_grad_value_(self.nets[d].parameters(), cfg.grad_clip)
            self.optimisers[d].step()
            with torch.no_grad():
                for pt, po in zip(self.targets[d].parameters(), self.nets[d].parameters()):
                    pt.lerp_(po, cfg.tau)
            metrics[f"loss/depth{d}"] = out.loss.item()
            metrics[f"td/depth{d}"] = out.delta.mean().item()
            metrics[f"td_translation/depth{d}"] = out.td_heads[:, 0].mean().item()
            if out.td_heads.shape[1] > 1:
                metrics[f"td_rotation/depth{d}"] = out.td_heads[:, 1:4].mean().item()
                metrics[f"td_gripper/depth{d}"] = out.td_heads[:, 4].mean().item()
            metrics[f"qreg/depth{d}"] = out.qreg.mean().item()
            if cfg.demo_margin > 0:
                metrics[f"demo_margin/depth{d}"] = out.margin.mean().item()
            metrics[f"q_chosen/depth{d}"] = out.q_chosen.mean().item()
            metrics[f"target/depth{d}"] = y.mean().item()
        self.update_step += 1
        metrics["update_step"] = float(self.update_step)
        return metrics, prio

    def _all_finite(self, outs) -> bool:
        """Every depth's loss and every gradient finite (checked before clipping, which would hide an inf)."""
        checks = [torch.isfinite(out.loss) for out in outs]
        checks += [torch.isfinite(p.grad).all() for p in self.nets.parameters() if p.grad is not None]
        return bool(torch.stack(checks).all())

    # ------------------------------------------------------------- persistence
    def weights(self) -> dict[str, torch.Tensor]:
        """Online networks only (what actors need), as ``net.{depth}.{param}``."""
        return {f"net.{k}": t.detach().cpu().clone() for k, t in self.nets.state_dict().items()}

    def load_weights(self, weights: dict[str, torch.Tensor]) -> None:
        """Swap in online weights (``net.*``; other keys are ignored), all or nothing.

        Names, shapes and finiteness are checked before anything is copied, because
        ``load_state_dict`` copies the tensors that match before it raises on the rest.
        Raises ValueError (naming the tensor) and leaves the networks untouched.
        """
        given = {k[4:]: t for k, t in weights.items() if k.startswith("net.")}
        expected = self.nets.state_dict()
        if given.keys() != expected.keys():
            odd = sorted(given.keys() ^ expected.keys())
            raise ValueError(f"weights do not fit these networks: {len(odd)} names differ, e.g. net.{odd[0]}")
        for name, t in given.items():
            if tuple(t.shape) != tuple(expected[name].shape):
                raise ValueError(f"net.{name}: shape {list(t.shape)}, expected {list(expected[name].shape)}")
            if t.is_floating_point() and not bool(torch.isfinite(t).all()):
                raise ValueError(f"net.{name}: non-finite values")
        self.nets.load_state_dict(given)

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Everything needed to resume bit-identically, as a flat dict of tensors."""
        state = self.weights()
        state.update({f"target.{k}": t.detach().cpu().clone() for k, t in self.targets.state_dict().items()})
        for d, opt in enumerate(self.optimisers):
            for i, s in opt.state_dict()["state"].items():
                for name, t in s.items():
                    state[f"adam.{d}.{i}.{name}"] = torch.as_tensor(t).detach().cpu().clone()
        state["update_step"] = torch.tensor(self.update_step, dtype=torch.int64)
        state["rng"] = self.generator.get_state().clone()
        return state

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.load_weights(state)
        self.targets.load_state_dict({k[7:]: t for k, t in state.items() if k.startswith("target.")})
        for d, opt in enumerate(self.optimisers):
            per_param: dict[int, dict[str, torch.Tensor]] = {}
            prefix = f"adam.{d}."
            for k, t in state.items():
                if k.startswith(prefix):
                    i, name = k[len(prefix) :].split(".", 1)
                    per_param.setdefault(int(i), {})[name] = t.clone()
            opt.load_state_dict({"state": per_param, "param_groups": opt.state_dict()["param_groups"]})
        self.update_step = int(state["update_step"])
        self.generator.set_state(state["rng"].clone())
