"""Typed configuration of the Q-attention cascade, plus the two presets.

Defaults are the reference's (``conf/method/C2FARM.yaml``); ``paper()`` returns them,
``cpu_small()`` trades width and precision for speed on a 2-core CPU (numbers in README.md).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Literal

#: Length of the proprioception vector (spec §1).
LOW_DIM_SIZE = 11


@dataclass(frozen=True)
class QAttentionConfig:
    voxel_size: int = 16  #: voxels per axis at every depth (V)
    depths: int = 2  #: number of coarse-to-fine depths (one network each)
    scene_bounds: tuple[float, ...] = (-0.3, -0.5, 0.6, 0.7, 0.5, 1.6)  #: depth-0 box (xmin,ymin,zmin,xmax,ymax,zmax); per-task, overwritten by sim/learner
    bounds_offset: float | tuple[float, ...] = 0.15  #: half-width of the depth d>=1 cube (one value, or one per depth>=1)
    rotation_resolution: int = 5  #: degrees per Euler bin (72 bins per axis at 5)
    kernels: int = 64  #: encoder width K (levels K, 2K, 4K); reference 64
    head_width: int = 128  #: width of the two hidden layers of the rotation/gripper MLP; reference 128
    padding: Literal["zeros", "replicate"] = "replicate"  #: conv padding mode; reference 'replicate'
    bf16: bool | Literal["auto"] = "auto"  #: bf16 autocast of the networks (loss stays fp32); "auto" = on where the device has native bf16 (precision.py)
    cameras: tuple[str, ...] = ("front",)  #: camera names fused into one grid
    image_crop: int = 64  #: crop size (px) of non-wrist images at depth>=1; 0 = off, 64 = reference
    episode_length: int = 10  #: max decisions per episode (time feature of the proprioception)
    lr: float = 5e-4  #: Adam learning rate
    weight_decay: float = 1e-6  #: Adam (coupled L2) weight decay
    tau: float = 0.0025  #: soft target update rate, applied every update
    gamma: float = 0.99  #: discount
    grad_clip: float = 0.01  #: element-wise gradient clip by value
    lambda_trans_qreg: float = 1.0  #: L1 regulariser weight on all translation Q-values
    lambda_rot_qreg: float = 1.0  #: L1 regulariser weight on all rotation/gripper Q-values
    per_alpha: float = 0.7  #: PER exponent applied to the returned priorities
    demo_margin: float = 0.0  #: large-margin loss on demo rows (DQfD): every other choice's Q must sit this far below the demo's, per head; 0 = off, as the reference
    lambda_demo_margin: float = 1.0  #: weight of the demo margin loss beside the TD loss
    crop_augmentation: bool = True  #: shift the depth>=1 cube centre of demo transitions at label time
    crop_shift: float = 0.75  #: max shift per axis as a fraction of bounds_offset
    demo_yaw_augmentation: float = 0.0  #: max |yaw| (deg) by which each sampled demo row's scene, gripper and action turn about the vertical through the action (yaw_augmentation.py); 0 = off, as the reference
    reward_scale: float = 0.01  #: reward multiplier before the TD target (100 -> 1)
    epsilon: float = 0.0  #: exploration probability per depth / rotation axis / gripper (0.0 = greedy, as reference)
    exploration: Literal["gaussian", "uniform"] = "gaussian"  #: 'gaussian' = local jitter, 'uniform' = any voxel / bin
    explore_voxel_sigma: float = 1.5  #: std (voxels) of the gaussian voxel jitter
    explore_rotation_sigma: float = 3.0  #: std (bins) of the gaussian rotation-bin jitter

    def __post_init__(self) -> None:
        if len(self.scene_bounds) != 6:
            raise ValueError("scene_bounds needs 6 floats (min xyz, max xyz)")
        if self.voxel_size < 4 or self.voxel_size & (self.voxel_size - 1):
            raise ValueError("voxel_size must be a power of two >= 4")
        if 360 % self.rotation_resolution:
            raise ValueError("rotation_resolution must divide 360")
        if self.bf16 not in (True, False, "auto"):
            raise ValueError(f"bf16 must be true, false or 'auto', not {self.bf16!r}")
        if self.padding not in ("zeros", "replicate"):
            raise ValueError(f"padding must be 'zeros' or 'replicate', not {self.padding!r}")
        if not 0 <= self.demo_yaw_augmentation <= 180:
            raise ValueError("demo_yaw_augmentation must be between 0 and 180 degrees")
        if self.demo_margin < 0 or self.lambda_demo_margin < 0:
            raise ValueError("demo_margin and lambda_demo_margin must be >= 0")
        if isinstance(self.bounds_offset, (list, tuple)) and len(self.bounds_offset) < self.depths - 1:
            raise ValueError("bounds_offset needs one value per depth >= 1")

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


def paper() -> QAttentionConfig:
    """The paper / reference: 2 x 16^3, K=64, replicate padding (meant for a GPU learner; bf16 where native)."""
    return QAttentionConfig()


def cpu_small() -> QAttentionConfig:
    """What fits a 2-core CPU: K=32, zero padding, bf16 where native, the demo margin (BENCHMARKS.md has the measurements)."""
    return QAttentionConfig(kernels=32, head_width=64, padding="zeros", demo_margin=0.1)
