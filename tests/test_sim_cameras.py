"""Cameras: pixels and world points agree through K and the extrinsics; together they see the whole workspace."""

import numpy as np
import pytest

from actors.panda_env import PandaEnv
from actors.sim import SimConfig


@pytest.fixture(scope="module")
def observation():
    env = PandaEnv(SimConfig(task="pick_and_lift", cameras=("front", "left_shoulder", "right_shoulder", "wrist"),
                             image_size=64))
    obs = env.reset(seed=3)
    yield env, obs
    env.close()


def test_every_camera_gives_aligned_rgb_and_points(observation):
    _, obs = observation
    assert set(obs.cameras) == {"front", "left_shoulder", "right_shoulder", "wrist"}
    for frame in obs.cameras.values():
        assert frame.rgb.shape == (64, 64, 3) and frame.rgb.dtype == np.uint8
        assert frame.points.shape == (64, 64, 3)
        assert frame.intrinsics.shape == (3, 3) and frame.extrinsics.shape == (4, 4)


def test_projecting_a_point_recovers_its_pixel(observation):
    _, obs = observation
    rng = np.random.default_rng(0)
    for name, frame in obs.cameras.items():
        for v, u in rng.integers(0, 64, size=(20, 2)):
            p = np.append(frame.points[v, u].astype(np.float64), 1.0)
            cam = np.linalg.inv(frame.extrinsics.astype(np.float64))[:3] @ p
            uvw = frame.intrinsics.astype(np.float64) @ cam
            assert cam[2] > 0, name
            assert np.allclose(uvw[:2] / uvw[2], (u, v), atol=1e-2), name


def test_fused_cloud_covers_the_scene_bounds(observation):
    env, obs = observation
    lo, hi = np.array(env.scene_bounds[:3]), np.array(env.scene_bounds[3:])
    pts = np.concatenate([f.points.reshape(-1, 3) for f in obs.cameras.values()])
    pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
    # the table top inside the bounds, in 10 cm cells: every cell where the robot can act is seen
    cells = {(int(x), int(y)) for x, y in np.floor((pts[:, :2] - lo[:2]) / 0.1)}
    wanted = {(i, j) for i in range(3, 8) for j in range(1, 9)}  # x 0.2..0.7 m, y -0.4..0.4 m
    assert wanted <= cells
    assert pts[:, 2].max() > 0.2  # objects and the arm rise above the table


def test_wrist_camera_moves_with_the_hand():
    env = PandaEnv(SimConfig(task="reach_target", cameras=("wrist",), image_size=32))
    before = env.reset(seed=0).cameras["wrist"].extrinsics
    after = env.step(env.demo_waypoints()[0].action()).observation.cameras["wrist"].extrinsics
    env.close()
    assert np.linalg.norm(before[:3, 3] - after[:3, 3]) > 0.05
