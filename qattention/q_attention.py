"""One depth's Q-attention network (``Qattention3DNet``, spec §3).

Inception encoder (K, 2K, 4K, ... channels, one level per halving down to 4^3), proprio
embedding tiled over the grid, inception-upsample decoder with skips, per-voxel Q. The last
depth adds the rotation/gripper head on spatial-soft-argmax + global-max features (optionally also
the features at the translation Q's best voxel, ``best_voxel_features``). With
K=64, head 128, V=16 the parameter counts equal the reference's (879,553 / 1,186,459).
Configurable: width, head width, padding mode; bf16 is applied by the caller (autocast).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from .config import LOW_DIM_SIZE
from .voxelise import CHANNELS

SLOPE = 0.02  #: leaky-ReLU slope of the reference


def _init(layer: nn.Module, activation: bool) -> None:
    if activation:
        nn.init.kaiming_uniform_(layer.weight, a=SLOPE, nonlinearity="leaky_relu")
    else:
        nn.init.xavier_uniform_(layer.weight, gain=1.0)
    nn.init.zeros_(layer.bias)


class Conv3d(nn.Module):
    """Conv3d, 'same' padding in the chosen mode, optional leaky ReLU."""

    def __init__(self, cin: int, cout: int, k: int, padding: str, activation: bool = True):
        super().__init__()
        self.conv = nn.Conv3d(cin, cout, k, padding=k // 2, padding_mode=padding)
        self.activation = activation
        _init(self.conv, activation)

    def forward(self, x):
        x = self.conv(x)
        return F.leaky_relu(x, SLOPE) if self.activation else x


class Dense(nn.Module):
    def __init__(self, cin: int, cout: int, activation: bool = True):
        super().__init__()
        self.linear = nn.Linear(cin, cout)
        self.activation = activation
        _init(self.linear, activation)

    def forward(self, x):
        x = self.linear(x)
        return F.leaky_relu(x, SLOPE) if self.activation else x


class Inception(nn.Module):
    """Branches 1x1 (C/2), 1x1->3x3 (C/4), 1x1->3x3->3x3 (C/4); bottleneck width ``mid`` (32 in the reference)."""

    def __init__(self, cin: int, cout: int, mid: int, padding: str):
        super().__init__()
        self.a = Conv3d(cin, cout // 2, 1, padding)
        self.b = nn.Sequential(Conv3d(cin, mid, 1, padding), Conv3d(mid, cout // 4, 3, padding))
        self.c = nn.Sequential(
            Conv3d(cin, mid, 1, padding), Conv3d(mid, mid, 3, padding), Conv3d(mid, cout // 4, 3, padding)
        )

    def forward(self, x):
        return torch.cat([self.a(x), self.b(x), self.c(x)], 1)


class UpBlock(nn.Module):
    """Inception, trilinear x2 upsample, inception."""

    def __init__(self, cin: int, cout: int, mid: int, padding: str):
        super().__init__()
        self.pre = Inception(cin, cout, mid, padding)
        self.post = Inception(cout, cout, mid, padding)

    def forward(self, x):
        x = F.interpolate(self.pre(x), scale_factor=2, mode="trilinear", align_corners=False)
        return self.post(x)


def spatial_soft_argmax(x: torch.Tensor, temperature: float = 0.01) -> torch.Tensor:
    """[B, C, D, H, W] -> expected (x, y, z) position in [-1, 1] per channel, [B, 3C] (fp32 softmax)."""
    b, c = x.shape[:2]
    dims = x.shape[2:]
    p = torch.softmax(x.float().reshape(b, c, -1) / temperature, -1)
    axes = [torch.linspace(-1.0, 1.0, n, device=x.device) for n in dims]
    pos = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return (p @ pos).reshape(b, 3 * c)


def best_voxel_features(features: torch.Tensor, q_trans: torch.Tensor) -> torch.Tensor:
    """[B, C, V, V, V] features at each row's best voxel of ``q_trans`` [B, V, V, V] -> [B, C] (fp32).

    The whole cube's soft-argmax and max features say where things are, not what lies at the pose the
    translation head picks; whether to shut the gripper there (on the bottle, or short of it) is a
    property of that spot. The choice is detached, so the head stays a function of the state alone
    (the TD target's maximum over rotations and gripper is unchanged in kind).
    """
    b, c = features.shape[:2]
    best = q_trans.detach().reshape(b, -1).argmax(-1)
    return features.reshape(b, c, -1).gather(2, best[:, None, None].expand(b, c, 1))[..., 0].float()


class QAttentionNet(nn.Module):
    """Q-values for every voxel (and, if ``rotation_bins``, for rotation bins and gripper)."""

    def __init__(
        self,
        voxel_size: int = 16,
        kernels: int = 64,
        padding: str = "replicate",
        rotation_bins: int = 0,
        head_width: int = 128,
        low_dim_size: int = LOW_DIM_SIZE,
        head_reads_best_voxel: bool = False,
    ):
        super().__init__()
        k, mid = kernels, kernels // 2
        levels = max(int(math.log2(voxel_size)) - 2, 1)  # halvings until 4^3 (V=16: 2, V=32: 3, V=8: 1)
        self.rotation_bins = rotation_bins
        self.head_reads_best_voxel = head_reads_best_voxel
        self.input = Inception(CHANNELS, k, mid, padding)
        self.proprio = Dense(low_dim_size, k)
        self.down = nn.ModuleList([Inception(2 * k, k, mid, padding)])
        widths = [k]
        for i in range(levels):
            self.down.append(Inception(widths[-1], k * 2 ** (i + 1), mid, padding))
            widths.append(k * 2 ** (i + 1))
        self.up = nn.ModuleList()
        cin = widths[-1]
        for skip in reversed(widths[1:-1]):
            self.up.append(UpBlock(cin, k, mid, padding))
            cin = skip + k
        self.up.append(UpBlock(cin, k, mid, padding))
        self.final = Conv3d(2 * k, k, 3, padding)
        self.q_trans = Conv3d(k, 1, 3, padding, activation=False)
        if rotation_bins:
            feats = 4 * (sum(widths) + k) + (k if head_reads_best_voxel else 0)
            self.head = nn.Sequential(
                Dense(feats, head_width), Dense(head_width, head_width), Dense(head_width, 3 * rotation_bins + 2, False)
            )
        else:
            self.head = None

    def forward(self, grid: torch.Tensor, proprio: torch.Tensor):
        """grid [B, 10, V, V, V], proprio [B, 11] -> (q_trans [B, V, V, V], q_rot_grip [B, 3*bins+2] or None)."""
        x = self.input(grid)
        p = self.proprio(proprio)
        x = torch.cat([x, p[:, :, None, None, None].expand(-1, -1, *x.shape[2:])], 1)
        skips = [self.down[0](x)]
        for layer in self.down[1:]:
            skips.append(layer(F.max_pool3d(skips[-1], 3, 2, 1)))
        u = self.up[0](skips[-1])
        for layer, skip in zip(self.up[1:], reversed(skips[1:-1])):
            u = layer(torch.cat([skip, u], 1))
        f = self.final(torch.cat([skips[0], u], 1))
        q_trans = self.q_trans(f)[:, 0].float()
        if self.head is None:
            return q_trans, None
        feats = []
        for t in [*skips, f]:
            feats += [spatial_soft_argmax(t), torch.amax(t, dim=(2, 3, 4)).float()]
        if self.head_reads_best_voxel:
            feats.append(best_voxel_features(f, q_trans))
        q_rg = self.head(torch.cat(feats, 1)).float()
        return q_trans, q_rg


def build_networks(config) -> list[QAttentionNet]:
    """One network per depth; only the last has the rotation/gripper head."""
    return [
        QAttentionNet(
            config.voxel_size,
            config.kernels,
            config.padding,
            config.rotation_bins if d == config.depths - 1 else 0,
            config.head_width,
            head_reads_best_voxel=config.head_reads_best_voxel,
        )
        for d in range(config.depths)
    ]
