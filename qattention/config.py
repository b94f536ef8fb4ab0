"""Typed configuration of the Q-attention cascade, plus the two presets.

Defaults are the reference's (``conf/method/C2FARM.yaml``); ``paper()`` returns them,
``cpu_small()`` trades width and precision for speed on a 2-core CPU (numbers in BENCHMARKS.md).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Literal

#: Length of the proprioception vector (spec §1).
LOW_DIM_SIZE = 11


@dataclass(frozen=True)
class QAttentionConfig:
    voxel_size: int = 16  #: voxels per axis at every depth (V), a power of two >= 4
    depths: int = 2  #: number of coarse-to-fine depths (one network each), >= 1
    #: depth-0 box (xmin,ymin,zmin,xmax,ymax,zmax), min < max; per-task, overwritten by sim/learner
    scene_bounds: tuple[float, ...] = (-0.3, -0.5, 0.6, 0.7, 0.5, 1.6)
    #: half-width of the depth d>=1 cube, > 0 (one value, or one per depth>=1)
    bounds_offset: float | tuple[float, ...] = 0.15
    rotation_resolution: int = 5  #: degrees per Euler bin, a divisor of 360 (72 bins per axis at 5)
    kernels: int = 64  #: encoder width K (levels K, 2K, 4K), >= 1; reference 64
    head_width: int = 128  #: width of the two hidden layers of the rotation/gripper MLP, >= 1; reference 128
    #: the rotation/gripper head also reads the last depth's final features at the translation Q's best voxel, beside
    #: the whole cube's soft-argmax and max features (the reference's only input); a lever, off as the reference
    head_reads_best_voxel: bool = False
    padding: Literal["zeros", "replicate"] = "replicate"  #: conv padding mode; reference 'replicate'
    #: bf16 autocast of the networks (loss stays fp32); "auto" = on where the device has native bf16 (precision.py)
    bf16: bool | Literal["auto"] = "auto"
    cameras: tuple[str, ...] = ("front",)  #: camera names fused into one grid, at least one, each once
    image_crop: int = 64  #: crop size (px, >= 0) of non-wrist images at depth>=1; 0 = off, 64 = reference
    episode_length: int = 10  #: max decisions per episode (time feature of the proprioception), >= 1
    #: the proprioception's time value counts decisions (the reference); False holds it at +1: the keyframe is
    #: then told by the gripper and the scene alone (a named per-task lever, BENCHMARKS.md, the ladder)
    time_feature: bool = True
    lr: float = 5e-4  #: Adam learning rate, > 0
    weight_decay: float = 1e-6  #: Adam (coupled L2) weight decay, >= 0
    tau: float = 0.0025  #: soft target update rate, applied every update, in (0, 1]
    gamma: float = 0.99  #: discount, in [0, 1]
    grad_clip: float = 0.01  #: element-wise gradient clip by value, > 0
    lambda_trans_qreg: float = 1.0  #: L1 regulariser weight on all translation Q-values, >= 0
    lambda_rot_qreg: float = 1.0  #: L1 regulariser weight on all rotation/gripper Q-values, >= 0
    #: the last depth's translation TD weight; its 3 rotation and gripper TDs weigh 1/5 each. 0.2: the five heads
    #: averaged (the reference), which leaves the last depth's translation Q near 0 on 2-core budgets; 1.0: as much
    #: as every other depth's (BENCHMARKS.md, the ladder)
    last_translation_td: float = 0.2
    per_alpha: float = 0.7  #: PER exponent applied to the returned priorities, in [0, 1]
    #: large-margin loss on demo rows (DQfD): every other choice's Q must sit this far below the demo's, per head; 0 =
    #: off, as the reference
    demo_margin: float = 0.0
    lambda_demo_margin: float = 1.0  #: weight of the demo margin loss beside the TD loss, >= 0
    #: weight of each of the last depth's five heads' demo margins (translation, 3 rotation axes, gripper). 0.2: the
    #: five averaged, so the gripper's ranking weighs a fifth of depth 0's; 1.0: each head as much (BENCHMARKS.md)
    last_head_margin: float = 0.2
    crop_augmentation: bool = True  #: shift the depth>=1 cube centre of demo transitions at label time
    crop_shift: float = 0.75  #: max shift per axis as a fraction of bounds_offset, in [0, 1]
    #: max |yaw| (deg, in [0, 180]) by which each sampled demo row's scene, gripper and action turn about the vertical
    #: through the action (yaw_augmentation.py); 0 = off, as the reference
    demo_yaw_augmentation: float = 0.0
    reward_scale: float = 0.01  #: reward multiplier before the TD target (100 -> 1), > 0
    #: exploration probability per depth / rotation axis / gripper, in [0, 1] (0.0 = greedy, as reference)
    epsilon: float = 0.0
    exploration: Literal["gaussian", "uniform"] = "gaussian"  #: 'gaussian' = local jitter, 'uniform' = any voxel / bin
    explore_voxel_sigma: float = 1.5  #: std (voxels, >= 0) of the gaussian voxel jitter
    explore_rotation_sigma: float = 3.0  #: std (bins, >= 0) of the gaussian rotation-bin jitter

    def __post_init__(self) -> None:
        # Messages as protocol/config_checks.py's ("<field> must be <rule> (got <value>)"), kept
        # local: qattention/ imports nothing from the service around it.
        if len(self.scene_bounds) != 6:
            raise ValueError("scene_bounds needs 6 floats (min xyz, max xyz)")
        _range(self, None, None, "scene_bounds")
        if not all(lo < hi for lo, hi in zip(self.scene_bounds[:3], self.scene_bounds[3:])):
            raise ValueError(f"scene_bounds must have min < max on every axis (got {self.scene_bounds})")
        if self.voxel_size < 4 or self.voxel_size & (self.voxel_size - 1):
            raise ValueError(f"voxel_size must be a power of two >= 4 (got {self.voxel_size})")
        _range(self, 1, None, "depths", "kernels", "head_width", "episode_length")
        _range(self, 0, None, "bounds_offset", open_low=True)
        if isinstance(self.bounds_offset, (list, tuple)) and len(self.bounds_offset) < self.depths - 1:
            raise ValueError("bounds_offset needs one value per depth >= 1")
        _range(self, 1, 360, "rotation_resolution")
        if 360 % self.rotation_resolution:
            raise ValueError(f"rotation_resolution must divide 360 (got {self.rotation_resolution})")
        if self.bf16 not in (True, False, "auto"):
            raise ValueError(f"bf16 must be true, false or 'auto', not {self.bf16!r}")
        if self.padding not in ("zeros", "replicate"):
            raise ValueError(f"padding must be 'zeros' or 'replicate', not {self.padding!r}")
        if self.exploration not in ("gaussian", "uniform"):
            raise ValueError(f"exploration must be 'gaussian' or 'uniform', not {self.exploration!r}")
        if not self.cameras or len(set(self.cameras)) != len(self.cameras):
            raise ValueError(f"cameras must name at least one camera, each once (got {list(self.cameras)})")
        _range(self, 0, None, "lr", "grad_clip", "reward_scale", open_low=True)
        _range(self, 0, None, "image_crop", "weight_decay", "lambda_trans_qreg", "lambda_rot_qreg",
               "last_translation_td", "demo_margin", "lambda_demo_margin", "last_head_margin",
               "explore_voxel_sigma", "explore_rotation_sigma")
        _range(self, 0, 1, "tau", open_low=True)
        _range(self, 0, 1, "gamma", "per_alpha", "crop_shift", "epsilon")
        _range(self, 0, 180, "demo_yaw_augmentation")

    @property
    def rotation_bins(self) -> int:
        """Bins per Euler axis."""
        return 360 // self.rotation_resolution

    def offset(self, depth: int) -> float:
        """Half-width of the cube of ``depth`` (>= 1)."""
        if isinstance(self.bounds_offset, (list, tuple)):
            return float(self.bounds_offset[depth - 1])
        return float(self.bounds_offset)

    def replace(self, **changes) -> "QAttentionConfig":
        return replace(self, **changes)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "QAttentionConfig":
        d = dict(d)
        for k in ("scene_bounds", "cameras"):
            if k in d:
                d[k] = tuple(d[k])
        if isinstance(d.get("bounds_offset"), list):
            d["bounds_offset"] = tuple(d["bounds_offset"])
        return cls(**d)


def _range(cfg, low, high, *names: str, open_low: bool = False, open_high: bool = False) -> None:
    """Each named field (each item of a tuple field) is finite and within [low, high] (None: unbounded)."""
    for name in names:
        value = getattr(cfg, name)
        items = (
            [(f"{name}[{i}]", v) for i, v in enumerate(value)] if isinstance(value, (list, tuple)) else [(name, value)]
        )
        for where, v in items:
            ok = low is None or (v > low if open_low else v >= low)
            ok = ok and (high is None or (v < high if open_high else v <= high))
            if ok and math.isfinite(v):
                continue
            if low is None and high is None:
                rule = "a finite number"
            elif high is None:
                rule = f"{'>' if open_low else '>='} {low}"
            elif str(type(cfg).__dataclass_fields__[name].type) == "int" and not (open_low or open_high):
                rule = f"in {low}..{high}"
            else:
                rule = f"in {'(' if open_low else '['}{low}, {high}{')' if open_high else ']'}"
            finite = "finite and " if low is not None and high is None and not math.isfinite(v) else ""
            raise ValueError(f"{where} must be {finite}{rule} (got {v!r})")


def paper() -> QAttentionConfig:
    """The paper / reference: 2 x 16^3, K=64, replicate padding (meant for a GPU learner; bf16 where native)."""
    return QAttentionConfig()


def cpu_small() -> QAttentionConfig:
    """What fits a 2-core CPU: K=32, zero padding, bf16 where native, the demo margin (measured in BENCHMARKS.md).

    Its grid is (8,8,8), three depths of 8^3 in cubes of 30 and 15 cm: the same 1.9 cm last voxel as the
    paper's (16,16) at about a quarter of the update cost, and on lift_lid fewer updates to 80 % as well.
    """
    return QAttentionConfig(voxel_size=8, depths=3, bounds_offset=(0.15, 0.075), kernels=32, head_width=64,
                            padding="zeros", demo_margin=0.1)
