"""Acting coarse-to-fine (spec §4.2): accuracy of the cascade, cameras and crops, exploration."""

import numpy as np
import pytest
import torch

from protocol.observation import CameraFrame, Observation
from qattention import C2FARM, ObservationBatch, QAttentionConfig, descend
from qattention.action_codec import bins_to_rotation
from qattention.cascade import TOP_VOXELS
from qattention.crop import crop_images, gather_points, project_to_pixel
from qattention.reachability import inside_workspace, ranked_candidates
from qattention.synthetic import observation_arrays

CFG = QAttentionConfig(image_crop=0)  # 2 x 16^3 over the reference's 1 m cube


def occupancy_q(config):
    """A Q-function that attends to occupied voxels, with fixed rotation bins (7, 20, 50) and gripper open."""

    def q(grid, proprio):
        rg = torch.zeros(grid.shape[0], 3 * config.rotation_bins + 2)
        for axis, b in enumerate((7, 20, 50)):
            rg[:, axis * config.rotation_bins + b] = 1.0
        rg[:, -1] = 1.0
        return grid[:, 9], rg

    return q


def single_point_scene(targets, resolution=8):
    """Every pixel of one camera sees the target point."""
    b = len(targets)
    arrays = observation_arrays(b, ("front",), resolution, seed=0)
    arrays["front_points"] = np.broadcast_to(targets[:, None, None, :], (b, resolution, resolution, 3)).astype(
        np.float32
    )
    return ObservationBatch.from_arrays(arrays, ("front",))


def test_cascade_translation_error_is_under_a_centimetre_anywhere_in_the_scene():
    rng = np.random.default_rng(0)
    lo, hi = np.array(CFG.scene_bounds[:3]), np.array(CFG.scene_bounds[3:])
    targets = rng.uniform(lo, hi - 1e-4, (500, 3))
    targets[:8] = lo + (hi - lo - 1e-4) * np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)])  # corners
    result = descend(single_point_scene(targets), [occupancy_q(CFG)] * 2, CFG)
    err = np.abs(result.action[:, :3] - targets)
    assert err.max() <= 0.30 / 16 / 2 + 1e-6  # half a 1.875 cm voxel per axis: <= 0.94 cm
    assert result.voxel_indices.shape == (500, 2, 3) and result.attention_coordinates.shape == (500, 2, 3)
    np.testing.assert_allclose(result.attention_coordinates[:, 1], result.action[:, :3])
    # depth 1 was voxelised in the 0.30 m cube around the depth-0 choice
    np.testing.assert_allclose(result.bounds[:, 1, 3:] - result.bounds[:, 1, :3], 0.30, atol=1e-6)
    assert (result.rot_grip_indices == [7, 20, 50, 1]).all()


def test_each_depth_reports_its_best_voxels_best_first_the_greedy_choice_leading():
    """``top_voxels`` is what the live view draws: per depth the K best voxels' centres and Q."""

    def random_q(grid, proprio):  # distinct Q everywhere: one best voxel per depth
        q_trans = torch.rand(grid.shape[0], *grid.shape[2:], generator=torch.Generator().manual_seed(0))
        return q_trans, torch.zeros(grid.shape[0], 3 * CFG.rotation_bins + 2)

    targets = np.array([[0.2, 0.0, 1.0], [0.1, 0.1, 0.9]])
    result = descend(single_point_scene(targets), [random_q] * 2, CFG)
    assert result.top_voxels.shape == (2, CFG.depths, TOP_VOXELS, 4) and result.voxel_size == CFG.voxel_size
    best = result.top_voxels[:, :, 0]
    np.testing.assert_allclose(best[:, -1, :3], result.action[:, :3], atol=1e-6)  # the last depth's best is the pose
    np.testing.assert_allclose(best[..., :3], result.attention_coordinates, atol=1e-6)
    np.testing.assert_array_equal(best[..., 3], result.q_values)
    assert (np.diff(result.top_voxels[..., 3], axis=-1) <= 0).all()  # sorted, best first
    assert set(result.replay_elements()) == {"voxel_indices", "attention_coordinates", "rot_grip_indices"}


def test_projection_inverts_the_point_cloud_and_crops_follow_it():
    arrays = observation_arrays(2, ("front", "wrist"), resolution=64, seed=1)
    obs = ObservationBatch.from_arrays(arrays, ("front", "wrist"))
    rows, cols = np.meshgrid(np.arange(0, 64, 7), np.arange(0, 64, 5), indexing="ij")
    for r, c in zip(rows.ravel(), cols.ravel()):
        pix = project_to_pixel(obs.points["front"][:, r, c], obs.intrinsics["front"], obs.extrinsics["front"])
        assert pix.tolist() == [[r, c], [r, c]]
    window = crop_images(obs.points["front"], torch.tensor([[10, 60], [32, 32]]), 16)
    torch.testing.assert_close(window[0], obs.points["front"][0, 2:18, 48:64])  # clamped inside the image
    torch.testing.assert_close(window[1], obs.points["front"][1, 24:40, 24:40])
    pts, rgb = gather_points(obs, ("front", "wrist"), centre=obs.gripper_pose[:, :3], crop=16)
    assert pts.shape == (2, 16 * 16 + 64 * 64, 3)  # the wrist camera is never cropped
    assert rgb.min() >= -1 and rgb.max() <= 1


def test_agent_acts_on_protocol_observations():
    arrays = observation_arrays(2, ("front", "wrist"), resolution=32, seed=2)
    observations = [
        Observation(
            cameras={
                c: CameraFrame(
                    arrays[f"{c}_rgb"][i],
                    arrays[f"{c}_points"][i].astype(np.float16),
                    arrays[f"{c}_intrinsics"][i],
                    arrays[f"{c}_extrinsics"][i],
                )
                for c in ("front", "wrist")
            },
            gripper_pose=arrays["gripper_pose"][i],
            gripper_open=1.0,
            finger_positions=np.array([0.04, 0.04]),
            joint_positions=np.zeros(7),
            joint_velocities=np.zeros(7),
            step=i,
        )
        for i in range(2)
    ]
    cfg = QAttentionConfig(
        voxel_size=8, kernels=8, head_width=16, padding="zeros", cameras=("front", "wrist"), image_crop=16
    )
    obs = ObservationBatch.from_observations(observations, cfg.cameras, scene_bounds=cfg.scene_bounds)
    result = C2FARM(cfg, seed=0).act(obs)
    assert result.action.shape == (2, 8) and result.action.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(result.action[:, 3:7], axis=1), 1.0, atol=1e-5)
    assert set(result.replay_elements()) == {"voxel_indices", "attention_coordinates", "rot_grip_indices"}


@pytest.mark.parametrize("kind", ["gaussian", "uniform"])
def test_exploration_changes_choices_at_the_rate_asked(kind):
    rng = np.random.default_rng(3)
    targets = rng.uniform(CFG.scene_bounds[:3], np.array(CFG.scene_bounds[3:]) - 1e-3, (400, 3))
    obs = single_point_scene(targets)
    greedy = descend(obs, [occupancy_q(CFG)] * 2, CFG)
    always = CFG.replace(epsilon=1.0, exploration=kind)
    assert np.array_equal(descend(obs, [occupancy_q(always)] * 2, always, explore=False).action, greedy.action)
    g = torch.Generator().manual_seed(0)
    explored = descend(obs, [occupancy_q(always)] * 2, always, explore=True, generator=g)
    moved = (explored.voxel_indices != greedy.voxel_indices).any(-1).mean(0)
    assert (moved > 0.7).all()
    assert (explored.rot_grip_indices[:, :3] != greedy.rot_grip_indices[:, :3]).mean() > 0.7
    assert (explored.rot_grip_indices[:, 3] != greedy.rot_grip_indices[:, 3]).all()  # gripper flipped
    pitch = explored.rot_grip_indices[:, 1]
    assert pitch.min() >= 18 and pitch.max() <= 54  # stays in [-90, 90] deg
    some = CFG.replace(epsilon=0.25, exploration=kind)
    partly = descend(obs, [occupancy_q(some)] * 2, some, explore=True, generator=g)
    rate = (partly.rot_grip_indices[:, 3] != greedy.rot_grip_indices[:, 3]).mean()
    assert 0.15 < rate < 0.35


def graded_q(config, seed=0, occupied=1.0):
    """Q ``occupied`` on occupied voxels, else 0; rotation Q random in [0, 0.1) with a clear best (7, 20, 50)."""
    rot = torch.rand(3, config.rotation_bins, generator=torch.Generator().manual_seed(seed)) * 0.1
    for axis, b in enumerate((7, 20, 50)):
        rot[axis, b] = 1.0

    def q(grid, proprio):
        rg = torch.cat([rot.reshape(-1), torch.tensor([0.0, 1.0])]).expand(grid.shape[0], -1)
        return occupied * grid[:, 9], rg

    return q, rot


def test_an_unreachable_rotation_gives_way_to_the_best_reachable_one():
    targets = np.array([[0.2, 0.0, 1.0], [0.1, 0.1, 0.9]])
    q, rot = graded_q(CFG)
    first = descend(single_point_scene(targets), [q] * 2, CFG)
    banned = bins_to_rotation(torch.tensor([7, 20, 50]), CFG.rotation_resolution).numpy()
    asked = []

    def reachable(action):  # sample 0's first choice cannot be reached; everything else can
        asked.append(action)
        return not (np.allclose(action[:3], first.action[0, :3]) and np.allclose(action[3:7], banned))

    result = descend(single_point_scene(targets), [q] * 2, CFG, reachable=reachable, top_k=8)
    # The voxel stays (its translation Q dominates); one axis moves to its best bin at least
    # 30 degrees (6 bins) away from its argmax: the axis whose such bin has the highest Q.
    best, far = [7, 20, 50], []
    for axis in range(3):
        d = np.abs(np.arange(CFG.rotation_bins) - best[axis])
        q_far = np.where(np.minimum(d, CFG.rotation_bins - d) >= 6, rot[axis].numpy(), -np.inf)
        far.append((q_far.max(), axis, int(q_far.argmax())))
    _, axis, b = max(far)
    expected = tuple(b if a == axis else best[a] for a in range(3))
    assert result.rot_grip_indices[0, :3].tolist() == list(expected)
    assert result.reach_replaced.tolist() == [True, False] and result.reach_checks.tolist() == [2, 1]
    np.testing.assert_array_equal(result.voxel_indices, first.voxel_indices)
    # labels and action agree: the stored bins are the executed rotation
    np.testing.assert_allclose(result.action[0, 3:7],
                               bins_to_rotation(torch.tensor(expected), CFG.rotation_resolution).numpy(), atol=1e-6)
    np.testing.assert_array_equal(result.action[1], first.action[1])
    assert len(asked) == 3


def test_a_replaced_translation_keeps_labels_consistent_and_nothing_reachable_keeps_the_first_choice():
    targets = np.array([[0.2, 0.0, 1.0]])
    q, _ = graded_q(CFG, occupied=0.01)  # a weak voxel preference: other voxels outrank other rotations
    first = descend(single_point_scene(targets), [q] * 2, CFG)
    away = descend(single_point_scene(targets), [q] * 2, CFG, top_k=6,
                   reachable=lambda a: not np.allclose(a[:3], first.action[0, :3]))
    assert away.reach_replaced[0] and not np.allclose(away.action[0, :3], first.action[0, :3])
    np.testing.assert_allclose(away.attention_coordinates[0, -1], away.action[0, :3])
    np.testing.assert_array_equal(away.voxel_indices[0, 0], first.voxel_indices[0, 0])  # depth 0 unchanged
    assert away.q_values[0, -1] < first.q_values[0, -1]  # an unoccupied voxel's Q
    stuck = descend(single_point_scene(targets), [q] * 2, CFG, reachable=lambda a: False, top_k=6)
    np.testing.assert_array_equal(stuck.action, first.action)
    assert stuck.reach_checks.tolist() == [6] and not stuck.reach_replaced[0]
    off = descend(single_point_scene(targets), [q] * 2, CFG, reachable=lambda a: 1 / 0, top_k=0)
    assert off.reach_checks is None  # off: never asks


def test_candidates_stay_in_the_workspace_and_include_the_held_rotation():
    v, bins = 4, 12
    q_trans = torch.arange(v ** 3, dtype=torch.float32).reshape(v, v, v)  # the far corner is best
    q_rot = torch.zeros(3, bins)
    q_rot[:, 3] = 1.0
    held = torch.tensor([0, 6, 9])
    # a child cube that sticks out of the workspace on the high-x side: its last x-layer is outside
    bounds = torch.tensor([0.0, 0.0, 0.0, 0.4, 0.4, 0.4])
    workspace = torch.tensor([-1.0, -1.0, -1.0, 0.3, 1.0, 1.0])
    inside = inside_workspace(bounds, v, workspace)
    assert inside[:3].all() and not inside[3].any()
    voxels, rotations = ranked_candidates(q_trans, q_rot, 5, inside=inside, fallback_rotation=held)
    assert (voxels[:, 0] < 3).all()  # no candidate in the outside layer
    assert voxels[0].tolist() == [2, 3, 3] and rotations[0].tolist() == [3, 3, 3]
    assert len(voxels) == 5 and rotations[-1].tolist() == held.tolist() and voxels[-1].tolist() == [2, 3, 3]
    # nothing inside: no candidates at all
    none = ranked_candidates(q_trans, q_rot, 5, inside=torch.zeros(v, v, v, dtype=torch.bool))
    assert len(none[0]) == 0
