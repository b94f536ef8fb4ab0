"""Action codec of spec §4: Euler convention, label round trips, crop augmentation, proprioception."""

import math

import numpy as np
import torch

from qattention import QAttentionConfig, decode_action, encode_action
from qattention.action_codec import crop_noise, decode_translation, rotation_to_bins
from qattention.proprioception import proprioception
from qattention.rotation import euler_to_quaternion, quaternion_to_euler, quaternion_to_matrix
from qattention.voxelise import child_bounds, voxel_resolution

CFG = QAttentionConfig()  # paper: 2 x 16^3, 1 m scene, 5 degree bins
SCENE = torch.tensor(CFG.scene_bounds)


def rot(axis, deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    m = {
        "x": [[1, 0, 0], [0, c, -s], [0, s, c]],
        "y": [[c, 0, s], [0, 1, 0], [-s, 0, c]],
        "z": [[c, -s, 0], [s, c, 0], [0, 0, 1]],
    }
    return torch.tensor(m[axis], dtype=torch.float64)


def random_quaternions(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return q / q.norm(dim=1, keepdim=True)


def angle_diff(a, b):
    return (a - b + 180.0) % 360.0 - 180.0


def test_euler_is_extrinsic_xyz_like_scipy():
    # scipy: Rotation.from_euler('xyz', [a, b, c], degrees=True) == Rz(c) @ Ry(b) @ Rx(a)
    e = torch.tensor([30.0, -20.0, 100.0], dtype=torch.float64)
    expected = rot("z", 100.0) @ rot("y", -20.0) @ rot("x", 30.0)
    torch.testing.assert_close(quaternion_to_matrix(euler_to_quaternion(e)), expected)
    torch.testing.assert_close(quaternion_to_euler(euler_to_quaternion(e)), e)
    # a 90 degree yaw, known quaternion
    q = euler_to_quaternion(torch.tensor([0.0, 0.0, 90.0], dtype=torch.float64))
    torch.testing.assert_close(q, torch.tensor([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], dtype=torch.float64))


def test_quaternion_euler_round_trip_is_the_same_rotation():
    q = random_quaternions(2000)
    e = quaternion_to_euler(q)
    assert e[:, 1].abs().max() <= 90.0  # pitch in [-90, 90]
    torch.testing.assert_close(quaternion_to_matrix(euler_to_quaternion(e)), quaternion_to_matrix(q))
    # gimbal lock: third angle set to zero, rotation preserved
    locked = euler_to_quaternion(torch.tensor([[40.0, 90.0, 0.0], [10.0, -90.0, 25.0]], dtype=torch.float64))
    torch.testing.assert_close(quaternion_to_matrix(euler_to_quaternion(quaternion_to_euler(locked))),
                               quaternion_to_matrix(locked))


def test_rotation_bins_follow_the_reference_rounding():
    def bins(e):
        return rotation_to_bins(euler_to_quaternion(torch.tensor([e], dtype=torch.float64)), 5)[0].tolist()

    assert bins([0.0, 0.0, 0.0]) == [36, 36, 36]  # +180 deg offset
    assert bins([179.0, -87.6, -180.0]) == [0, 18, 0]  # 180 + 179 -> bin 72 wraps to 0; pitch's lowest bin is 18
    assert bins([2.5 + 1e-6, 0.0, 7.5 - 1e-6])[0] == 37 and bins([0.0, 0.0, 7.5 - 1e-6])[2] == 37


def test_codec_round_trip_within_half_a_voxel_and_half_a_bin():
    n = 4000
    g = torch.Generator().manual_seed(1)
    xyz = SCENE[:3] + (SCENE[3:] - SCENE[:3]) * torch.rand(n, 3, generator=g) * 0.9999
    q = random_quaternions(n, seed=2)
    grip = (torch.rand(n, generator=g) > 0.5).float()
    action = torch.cat([xyz, q.float(), grip[:, None]], 1)
    labels = encode_action(action, SCENE, CFG)
    assert labels.voxel_indices.shape == (n, 2, 3) and labels.rot_grip.shape == (n, 4)
    decoded = decode_action(labels.voxel_indices, labels.rot_grip, SCENE, CFG)
    finest = (0.30 / 16) / 2  # half a depth-1 voxel, 0.94 cm
    assert (decoded[:, :3] - xyz).abs().max() <= finest + 1e-6
    assert (decoded[:, :3] - xyz).abs().max() <= 0.01  # the "near-lossless" 1 cm claim, per axis
    # per Euler axis within 2.5 deg of the original angles
    err = angle_diff(quaternion_to_euler(q), labels.rotation.double() * 5 - 180).abs()
    assert err.max() <= 2.5 + 1e-6
    # and the decoded quaternion is the rotation of those bin angles
    torch.testing.assert_close(quaternion_to_euler(decoded[:, 3:7].double())[:, 1],
                               labels.rotation[:, 1].double() * 5 - 180, atol=1e-3, rtol=0)
    assert torch.equal(decoded[:, 7], grip)


def test_crop_augmentation_labels_agree_with_the_bounds_used():
    n = 2000
    g = torch.Generator().manual_seed(3)
    xyz = SCENE[:3] + (SCENE[3:] - SCENE[:3]) * torch.rand(n, 3, generator=g) * 0.9999
    noise = crop_noise(n, CFG, g)
    assert noise.abs().max() <= 0.75 * 0.15 and noise.abs().max() > 0.1
    idx, coords, bounds = encode_translation_with(xyz, noise)
    # depth-1 bounds are the shifted centre actually stored (spec §10.1), and still contain the target
    torch.testing.assert_close(bounds[:, 1], child_bounds(coords[:, 0], 0.15))
    assert ((xyz >= bounds[:, 1, :3]) & (xyz < bounds[:, 1, 3:])).all()
    # the final coordinate is within half a fine voxel of the target
    assert (coords[:, 1] - xyz).abs().max() <= voxel_resolution(bounds[0, 1], 16).max() / 2 + 1e-6
    # without noise, decoding the labels rebuilds the same final coordinate
    idx0, coords0, _ = encode_translation_with(xyz, None)
    torch.testing.assert_close(decode_translation(idx0, SCENE, CFG), coords0[:, 1])


def encode_translation_with(xyz, noise):
    from qattention.action_codec import encode_translation

    return encode_translation(xyz, SCENE, CFG, noise)


def test_proprioception_layout_and_time_feature():
    pose = np.array([0.1, 0.2, 0.3, 0, 0, 0, 1], np.float32)
    s = proprioception(1.0, pose, np.array([0.05, -0.01]), 0, 10)
    np.testing.assert_allclose(s, [1, 0.1, 0.2, 0.3, 0, 0, 0, 1, 0.04, 0.0, 1.0], atol=1e-7)
    assert s.dtype == np.float32 and s.shape == (11,)
    assert proprioception(0.0, pose, np.zeros(2), 9, 10)[-1] == -1.0  # last decision
    t = proprioception(torch.zeros(3), torch.zeros(3, 7), torch.zeros(3, 2), torch.tensor([0, 3, 9]), 10)
    assert t.shape == (3, 11)
    torch.testing.assert_close(t[:, -1], torch.tensor([1.0, 1 / 3, -1.0]))
    # without the time value every step reads as the first decision: the gripper and the scene name the keyframe
    untimed = proprioception(torch.zeros(3), torch.zeros(3, 7), torch.zeros(3, 2), torch.tensor([0, 3, 9]), 10, False)
    torch.testing.assert_close(untimed[:, -1], torch.ones(3))
    assert proprioception(0.0, pose, np.zeros(2), 9, 10, with_time=False)[-1] == 1.0
