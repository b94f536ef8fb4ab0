"""Q-attention network of spec §3: the reference's parameter counts and shapes for other sizes."""

import pytest
import torch

from qattention import QAttentionConfig, build_networks, cpu_small, paper
from qattention.q_attention import QAttentionNet, best_voxel_features


def n_params(net):
    return sum(p.numel() for p in net.parameters())


def test_paper_preset_has_the_reference_parameter_counts():
    depth0, depth1 = build_networks(paper())
    assert n_params(depth0) == 879_553
    assert n_params(depth1) == 1_186_459  # + rotation/gripper head: 3 x 72 bins + 2
    assert depth0.head is None and depth1.head[-1].linear.out_features == 218


def test_cpu_small_preset_is_smaller_but_same_shape_of_output():
    config = cpu_small()
    small = build_networks(config)
    assert len(small) == 3 and config.voxel_size == 8  # the (8,8,8) grid
    assert n_params(small[-1]) < n_params(build_networks(paper())[1]) / 3
    q, rg = small[-1](torch.zeros(2, 10, 8, 8, 8), torch.zeros(2, 11))
    assert q.shape == (2, 8, 8, 8) and rg.shape == (2, 218)


@pytest.mark.parametrize("voxel_size", [8, 32])
def test_other_voxel_sizes_add_or_remove_levels(voxel_size):
    torch.manual_seed(0)
    net = QAttentionNet(voxel_size, kernels=8, padding="zeros", rotation_bins=36, head_width=16)
    q, rg = net(torch.randn(1, 10, voxel_size, voxel_size, voxel_size), torch.randn(1, 11))
    assert q.shape == (1, voxel_size, voxel_size, voxel_size) and rg.shape == (1, 3 * 36 + 2)
    assert len(net.down) == (2 if voxel_size == 8 else 4)


def test_padding_mode_changes_outputs_not_parameters():
    cfg = QAttentionConfig(voxel_size=8, kernels=8, head_width=16)
    torch.manual_seed(0)
    rep = build_networks(cfg.replace(padding="replicate"))[1]
    zer = build_networks(cfg.replace(padding="zeros"))[1]
    zer.load_state_dict(rep.state_dict())
    x, p = torch.randn(1, 10, 8, 8, 8), torch.randn(1, 11)
    assert not torch.allclose(rep(x, p)[0], zer(x, p)[0])


def test_bf16_autocast_outputs_stay_float32_and_close():
    torch.manual_seed(0)
    net = QAttentionNet(8, kernels=8, padding="zeros", rotation_bins=36, head_width=16)
    x, p = torch.randn(1, 10, 8, 8, 8), torch.randn(1, 11)
    q32, rg32 = net(x, p)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        q16, rg16 = net(x, p)
    assert q16.dtype == torch.float32 and rg16.dtype == torch.float32
    assert (q16 - q32).abs().max() < 0.1 * q32.abs().max() + 0.05


def test_bf16_auto_is_on_only_where_the_device_has_native_bf16():
    from qattention import C2FARM
    from qattention.precision import NATIVE_BF16_CPU_FLAGS, cpu_flags, use_bf16

    cpu = torch.device("cpu")
    native = bool(NATIVE_BF16_CPU_FLAGS & cpu_flags())
    small = QAttentionConfig(voxel_size=8, kernels=8, head_width=16, rotation_resolution=10)
    assert C2FARM(small).bf16 is native  # the default is "auto"
    assert use_bf16(True, cpu) and not use_bf16(False, cpu)  # an explicit choice is kept
    with pytest.raises(ValueError, match="bf16"):
        QAttentionConfig(bf16="yes")


def test_the_head_can_read_the_features_at_the_translation_q_best_voxel():
    features = torch.arange(2 * 3 * 64, dtype=torch.float32).reshape(2, 3, 4, 4, 4)
    q_trans = torch.zeros(2, 4, 4, 4)
    q_trans[0, 1, 2, 3] = 1.0
    q_trans[1, 3, 0, 0] = 1.0
    picked = best_voxel_features(features, q_trans)
    assert torch.equal(picked, torch.stack([features[0, :, 1, 2, 3], features[1, :, 3, 0, 0]]))

    cfg = QAttentionConfig(voxel_size=8, kernels=8, head_width=16)
    torch.manual_seed(0)
    plain = build_networks(cfg)[1]
    torch.manual_seed(0)
    reading = build_networks(cfg.replace(head_reads_best_voxel=True))[1]
    assert n_params(reading) == n_params(plain) + 8 * 16  # one more input of K=8 to the head's first layer
    q, rg = reading(torch.randn(2, 10, 8, 8, 8), torch.randn(2, 11))
    assert q.shape == (2, 8, 8, 8) and rg.shape == (2, 3 * 72 + 2) and torch.isfinite(rg).all()
