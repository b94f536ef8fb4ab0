"""Moving on (qattention/repeats.py): a choice that repeats the gripper's pose gives way to the best one that moves."""

import numpy as np
import torch

from qattention import ObservationBatch, QAttentionConfig, descend
from qattention.action_codec import bins_to_rotation
from qattention.repeats import Held, repeats_pose
from qattention.synthetic import observation_arrays

CFG = QAttentionConfig(image_crop=0)
HELD = (7, 20, 50)  #: the rotation bins the Q-function prefers, and the gripper holds


def gripper_at_target(targets, gripper_open=1.0, resolution=8):
    """Every pixel of one camera sees the target point, and the gripper is there, in the ``HELD`` rotation."""
    b = len(targets)
    arrays = observation_arrays(b, ("front",), resolution, seed=0)
    arrays["front_points"] = np.broadcast_to(targets[:, None, None, :], (b, resolution, resolution, 3)).astype(
        np.float32)
    quat = bins_to_rotation(torch.tensor(HELD), CFG.rotation_resolution).numpy()
    arrays["gripper_pose"] = np.concatenate([targets, np.broadcast_to(quat, (b, 4))], 1).astype(np.float32)
    arrays["gripper_open"] = np.full(b, gripper_open, np.float32)
    return ObservationBatch.from_arrays(arrays, ("front",))


def q_function(grip_values):
    """Translation Q 1 on the occupied voxel; rotation Q 1 at ``HELD``, below 0.1 elsewhere; gripper Q as given."""
    rot = torch.rand(3, CFG.rotation_bins, generator=torch.Generator().manual_seed(0)) * 0.1
    for axis, b in enumerate(HELD):
        rot[axis, b] = 1.0
    rot_grip = torch.cat([rot.reshape(-1), torch.tensor(grip_values)])

    def q(grid, proprio):
        return grid[:, 9], rot_grip.expand(grid.shape[0], -1)

    return q


def test_the_greedy_choice_at_the_gripper_repeats_its_pose_and_the_rule_is_off_by_default():
    obs = gripper_at_target(np.array([[0.2, 0.0, 1.0]]))
    q = q_function([0.0, 1.0])  # open
    greedy = descend(obs, [q] * 2, CFG)
    assert greedy.repeat_skipped is None
    assert greedy.rot_grip_indices[0].tolist() == [*HELD, 1]
    last = torch.from_numpy(greedy.bounds[0, -1])
    held = Held(obs.gripper_pose[0, :3], torch.tensor(HELD), 1.0)
    assert repeats_pose(torch.from_numpy(greedy.action[0, :3]), torch.tensor(HELD), 1, last, CFG.voxel_size, held)
    assert not repeats_pose(torch.from_numpy(greedy.action[0, :3]), torch.tensor(HELD), 0, last, CFG.voxel_size,
                            held)  # closing the gripper is a move


def test_a_close_second_gripper_value_turns_a_repeat_into_a_grasp():
    obs = gripper_at_target(np.array([[0.2, 0.0, 1.0]]))
    greedy = descend(obs, [q_function([0.9, 1.0])] * 2, CFG)
    moved = descend(obs, [q_function([0.9, 1.0])] * 2, CFG, skip_repeats=True)
    assert moved.repeat_skipped.tolist() == [True]
    # the toggle (1 + 1 + 0.9) beats every other voxel (0 + 1 + 1) and every other rotation (1 + < 0.7 + 1)
    assert moved.rot_grip_indices[0].tolist() == [*HELD, 0] and moved.action[0, 7] == 0.0
    np.testing.assert_array_equal(moved.action[0, :7], greedy.action[0, :7])


def test_a_sure_gripper_makes_the_rule_turn_the_hand_instead_and_reachability_is_asked():
    obs = gripper_at_target(np.array([[0.2, 0.0, 1.0]]))
    q = q_function([0.0, 1.0])
    moved = descend(obs, [q] * 2, CFG, skip_repeats=True)
    assert moved.repeat_skipped.tolist() == [True] and moved.action[0, 7] == 1.0
    # same voxel, one axis turned to its best bin 30 degrees or more away (other voxels score 0 + 1 + 1 < 2 + 2/3)
    greedy = descend(obs, [q] * 2, CFG)
    assert (moved.voxel_indices == greedy.voxel_indices).all()
    turned = [a for a in range(3) if moved.rot_grip_indices[0, a] != HELD[a]]
    assert len(turned) == 1
    np.testing.assert_allclose(moved.action[0, 3:7], bins_to_rotation(
        torch.from_numpy(moved.rot_grip_indices[0, :3]), CFG.rotation_resolution).numpy(), atol=1e-6)
    # with a reachability test, unreachable candidates are passed over: the gripper toggled, if the turn is not
    toggled = descend(obs, [q] * 2, CFG, skip_repeats=True, top_k=4,
                      reachable=lambda a: bool(np.allclose(a[3:7], greedy.action[0, 3:7])))
    assert toggled.repeat_skipped.tolist() == [True] and toggled.rot_grip_indices[0].tolist() == [*HELD, 0]
    # ... and where nothing but the repeat is reachable, it stands
    stuck = descend(obs, [q] * 2, CFG, skip_repeats=True, top_k=4,
                    reachable=lambda a: bool(np.allclose(a, greedy.action[0])))
    assert stuck.repeat_skipped.tolist() == [False] and stuck.rot_grip_indices[0].tolist() == [*HELD, 1]
    assert stuck.reach_checks[0] > 1


def test_a_choice_that_moves_is_left_alone():
    obs = gripper_at_target(np.array([[0.2, 0.0, 1.0], [0.1, 0.1, 0.9]]))
    obs.gripper_pose[1, :3] += torch.tensor([0.05, 0.0, 0.0])  # sample 1's gripper is 5 cm from the target
    q = q_function([0.0, 1.0])
    moved = descend(obs, [q] * 2, CFG, skip_repeats=True)
    assert moved.repeat_skipped.tolist() == [True, False]
    np.testing.assert_array_equal(moved.action[1], descend(obs, [q] * 2, CFG).action[1])
