"""Robot-rig cameras keep the simulator's CameraFrame contract: K, OpenCV extrinsics, world points.

The MuJoCo stand-in renders franky-sim's scene; the red reach target must appear where K and the
extrinsics project it, and the points seen there must lie on its surface.
"""

from __future__ import annotations

import numpy as np
import pytest

from actors.robot.cameras import load_extrinsics, matrix_quaternion, quaternion_matrix, save_extrinsics, square_frame


def test_extrinsics_yaml_round_trip(tmp_path):
    rot = quaternion_matrix(np.array([0.1, 0.8, -0.5, 0.3]) / np.linalg.norm([0.1, 0.8, -0.5, 0.3]))
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, [1.2, -0.1, 0.6]
    save_extrinsics(tmp_path / "front.yaml", pose)
    assert np.allclose(load_extrinsics(tmp_path / "front.yaml"), pose, atol=1e-9)
    assert np.allclose(quaternion_matrix(matrix_quaternion(rot)), rot)


def test_extrinsics_file_with_a_bad_rotation_is_refused(tmp_path):
    (tmp_path / "bad.yaml").write_text("translation: [0, 0, 1]\nrotation_xyzw: [0, 0, 0, 2]\n")
    with pytest.raises(ValueError, match="unit quaternion"):
        load_extrinsics(tmp_path / "bad.yaml")


def test_square_frame_crops_scales_and_keeps_projection_exact():
    """A 640x480 device image becomes 128x128; a pixel's point still projects back onto that pixel."""
    h, w = 480, 640
    k = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])
    depth = np.full((h, w), 0.8, np.float32)
    depth[:10] = 0.0  # no return from the sensor
    rgb = np.zeros((h, w, 3), np.uint8)
    frame = square_frame(rgb, depth, k, np.eye(4), 128)
    assert frame.rgb.shape == (128, 128, 3) and frame.points.shape == (128, 128, 3)
    assert np.isnan(frame.points[0]).all()  # invalid depth is NaN, which voxelisation drops
    kk = frame.intrinsics.astype(np.float64)
    for v, u in [(64, 64), (100, 20), (127, 127)]:
        uvw = kk @ frame.points[v, u].astype(np.float64)
        assert np.allclose(uvw[:2] / uvw[2], (u, v), atol=1e-3)


def test_mujoco_stand_in_sees_the_target_where_the_matrices_say():
    pytest.importorskip("franky_sim")
    from actors.robot.franky_sim import TARGET_RADIUS, FrankySim

    with FrankySim() as sim:
        sim.set_target((0.55, 0.1, 0.15))
        frame = sim.camera("front").capture()
    target = np.array([0.55, 0.1, 0.15])
    world_to_cam = np.linalg.inv(frame.extrinsics.astype(np.float64))
    uvw = frame.intrinsics.astype(np.float64) @ (world_to_cam[:3, :3] @ target + world_to_cam[:3, 3])
    u, v = np.round(uvw[:2] / uvw[2]).astype(int)
    assert 0 <= u < 128 and 0 <= v < 128
    r, g, b = frame.rgb[v, u].astype(int)
    assert r > 120 and r > 2 * g and r > 2 * b, frame.rgb[v, u]  # red target
    assert abs(np.linalg.norm(frame.points[v, u] - target) - TARGET_RADIUS) < 0.01  # on its surface
    table = frame.points[120, 64]  # bottom of the image: the table plane in front of the robot
    assert abs(table[2]) < 0.01
