"""Yaw augmentation of demo rows: the scene, the gripper and the action turn together about the target."""

import numpy as np
import pytest
import torch

from qattention import C2FARM, QAttentionConfig, TransitionBatch
from qattention.action_codec import encode_action
from qattention.rotation import euler_to_quaternion, quaternion_to_euler
from qattention.synthetic import transition_arrays
from qattention.yaw_augmentation import augment_yaw, turn_demo_rows, turn_points

CFG = QAttentionConfig(voxel_size=8, kernels=8, head_width=32, padding="zeros", image_crop=16,
                       rotation_resolution=10, crop_augmentation=False)


def top_down_batch(n=6, demo_rows=(0, 2, 4)):
    arrays = transition_arrays(n, resolution=32, seed=3)
    yaws = np.linspace(-40, 40, n)
    arrays["action"][:, 3:7] = euler_to_quaternion(torch.tensor([[180.0, 0.0, y] for y in yaws])).numpy()
    arrays["is_demo"][:] = False
    arrays["is_demo"][list(demo_rows)] = True
    return TransitionBatch.from_arrays(arrays, CFG.cameras)


def test_agent_rows_come_back_bit_identical_and_demo_rows_turn():
    b = top_down_batch()
    out = augment_yaw(b, 45.0, torch.Generator().manual_seed(0))
    agent, demo = ~b.is_demo, b.is_demo
    for before, after in [
        (b.obs.points["front"], out.obs.points["front"]),
        (b.action, out.action),
        (b.obs.gripper_pose, out.obs.gripper_pose),
        (b.next_obs.points["front"], out.next_obs.points["front"]),
    ]:
        assert torch.equal(before[agent], after[agent])
        assert not torch.equal(before[demo], after[demo])
    # The target point stays where it is; heights never change; points keep their distance to it.
    torch.testing.assert_close(out.action[:, :3], b.action[:, :3])
    p0, p1 = b.obs.points["front"], out.obs.points["front"]
    torch.testing.assert_close(p1[..., 2], p0[..., 2])
    centre = b.action[:, None, None, :2]
    torch.testing.assert_close((p1[..., :2] - centre).norm(dim=-1), (p0[..., :2] - centre).norm(dim=-1))


def test_translation_labels_stay_and_the_yaw_label_turns_with_the_scene():
    b = top_down_batch(demo_rows=range(6))
    # 30 degrees is a whole number of 10-degree bins: the yaw bin moves by exactly 3.
    angle = torch.full((6,), np.deg2rad(30.0))
    turned = turn_points(b.obs.points["front"], b.action[:, :3], angle)
    assert turned.shape == b.obs.points["front"].shape
    out = turn_demo_rows(b, torch.full((6,), 30.0))
    before = encode_action(b.action, torch.tensor(CFG.scene_bounds), CFG)
    after = encode_action(out.action, torch.tensor(CFG.scene_bounds), CFG)
    assert torch.equal(before.voxel_indices, after.voxel_indices)
    assert torch.equal(before.rotation[:, :2], after.rotation[:, :2])  # still top-down
    assert torch.equal((before.rotation[:, 2] + 3) % CFG.rotation_bins, after.rotation[:, 2])
    yaw = quaternion_to_euler(out.action[:, 3:7].double())[:, 2] - quaternion_to_euler(b.action[:, 3:7].double())[:, 2]
    torch.testing.assert_close(yaw, torch.full((6,), 30.0, dtype=torch.float64), atol=1e-3, rtol=0)
    torch.testing.assert_close(out.obs.points["front"], turned)


def test_off_by_default_as_the_reference_and_bounded():
    b = top_down_batch()
    assert QAttentionConfig().demo_yaw_augmentation == 0
    assert augment_yaw(b, 0.0) is b
    with pytest.raises(ValueError, match="demo_yaw_augmentation"):
        QAttentionConfig(demo_yaw_augmentation=-1)


def test_an_update_with_yaw_augmentation_learns_and_stays_finite():
    agent = C2FARM(CFG.replace(demo_yaw_augmentation=45.0), seed=0)
    metrics, prio = agent.update(top_down_batch())
    assert np.isfinite(prio).all() and metrics["skipped_nonfinite"] == 0.0
