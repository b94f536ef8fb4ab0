"""No batch can poison training: non-finite batches are rejected, non-finite updates skipped,
NaN point clouds never reach the loss, and a non-finite state is never checkpointed."""

import numpy as np
import pytest
import torch

from learner.checkpoint import complete_checkpoints
from learner.config import LearnerConfig
from learner.train import Learner
from protocol.role import RoleContext
from qattention import C2FARM, QAttentionConfig, TransitionBatch
from qattention.synthetic import transition_arrays

TINY = QAttentionConfig(voxel_size=8, kernels=4, head_width=16, padding="zeros", image_crop=16, rotation_resolution=30)


def arrays(n=3, seed=0):
    a = transition_arrays(n, resolution=32, seed=seed)
    a["indices"] = np.arange(n, dtype=np.int64)
    a["keys"] = np.arange(100, 100 + n, dtype=np.int64)
    return a


def state(agent: C2FARM) -> dict[str, torch.Tensor]:
    return {k: t.clone() for k, t in agent.state_dict().items()}


def assert_unchanged(before, agent):
    """Networks, targets, Adam and the step are as they were (the crop-noise RNG may have moved on)."""
    after = agent.state_dict()
    assert before.keys() == after.keys()
    for k in before.keys() - {"rng"}:
        assert torch.equal(before[k], after[k]), k


def test_a_nan_reward_skips_the_whole_update_and_priorities_stay_finite():
    agent = C2FARM(TINY, seed=0)
    agent.update(TransitionBatch.from_arrays(arrays(), TINY.cameras))  # Adam state exists from here on
    before = state(agent)
    poisoned = arrays()
    poisoned["reward"][1] = np.nan
    metrics, prio = agent.update(TransitionBatch.from_arrays(poisoned, TINY.cameras))
    assert metrics == {"skipped_nonfinite": 1.0, "update_step": 1.0} and agent.skipped_nonfinite == 1
    assert_unchanged(before, agent)  # no depth stepped, no target moved, Adam untouched
    assert np.isfinite(prio).all() and prio[1] == 0 and (prio[[0, 2]] > 0).all()

    metrics, prio = agent.update(TransitionBatch.from_arrays(arrays(), TINY.cameras))  # training carries on
    assert metrics["skipped_nonfinite"] == 0 and metrics["update_step"] == 2.0
    assert all(np.isfinite(v) for v in metrics.values()) and np.isfinite(prio).all()
    assert all(torch.isfinite(t).all() for t in agent.weights().values())


def test_a_non_finite_gradient_with_a_finite_loss_is_skipped_too():
    agent = C2FARM(TINY, seed=0)
    before = state(agent)
    # Only depth 1's gradient goes bad: depth 0 must not step either (all or nothing).
    hook = next(agent.nets[1].parameters()).register_hook(lambda g: g * float("inf"))
    metrics, prio = agent.update(TransitionBatch.from_arrays(arrays(), TINY.cameras))
    hook.remove()
    assert metrics["skipped_nonfinite"] == 1 and np.isfinite(prio).all()
    assert_unchanged(before, agent)


def test_nan_points_never_reach_the_loss():
    a = arrays(seed=1)
    for name in ("front_points", "front_points_tp1"):
        a[name][:, ::3] = np.nan  # invalid depth from a real camera: a third of the rows of pixels
        a[name][:, 1, :4] = np.inf
    agent = C2FARM(TINY, seed=0)
    metrics, prio = agent.update(TransitionBatch.from_arrays(a, TINY.cameras))
    assert metrics["skipped_nonfinite"] == 0
    assert all(np.isfinite(v) for v in metrics.values()) and np.isfinite(prio).all()
    assert all(p.grad is None or torch.isfinite(p.grad).all() for p in agent.nets.parameters())
    assert all(torch.isfinite(t).all() for t in agent.weights().values())


@pytest.fixture
def learner(tmp_path):
    ctx = RoleContext("run-1", "learner", tmp_path)
    return Learner(LearnerConfig(device="cpu", checkpoint_keep=2), TINY, ctx)


def test_the_learner_rejects_a_poisoned_batch_and_quarantines_its_rows(learner):
    before = state(learner.agent)
    a = arrays(4)
    a["front_extrinsics_tp1"][2, 0, 0] = np.inf  # anything but a point cloud must be finite
    metrics, rows, prio = learner.train_step(a)
    assert metrics == {} and learner.step == 0 and learner.health["rejected_batches"] == 1
    assert rows.tolist() == [2] and prio.tolist() == [0.0]  # only the poisoned row gets a new priority
    assert_unchanged(before, learner.agent)
    assert learner.counters()["rejected_batches"] == 1

    metrics, rows, prio = learner.train_step(arrays(4))  # a clean batch trains
    assert metrics["skipped_nonfinite"] == 0 and learner.step == 1 and rows.tolist() == [0, 1, 2, 3]


def with_labels(a, voxel=(1, 2, 3), rot_grip=(0, 5, 11, 1)):
    """Act-time labels as an actor records them (observation extras), valid for TINY."""
    n = len(a["indices"])
    a["extra_voxel_indices"] = np.tile(np.array(voxel, np.int64), (n, TINY.depths, 1))
    a["extra_attention_coordinates"] = np.zeros((n, TINY.depths, 3), np.float32)
    a["extra_rot_grip_indices"] = np.tile(np.array(rot_grip, np.int64), (n, 1))
    return a


@pytest.mark.parametrize("label, row, value", [
    ("extra_voxel_indices", (1, 0, 2), TINY.voxel_size),          # one past the grid
    ("extra_rot_grip_indices", (1, 2), TINY.rotation_bins),       # one past the Euler bins
    ("extra_rot_grip_indices", (1, 3), 2),                        # the gripper has two bins
])
def test_act_time_labels_outside_the_network_are_rejected_not_gathered(learner, label, row, value):
    """The wire only knows labels are >= 0; the learner knows its grid and bins."""
    a = with_labels(arrays(3))
    a[label][row] = value
    metrics, rows, prio = learner.train_step(a)
    assert metrics == {} and learner.step == 0 and rows.tolist() == [1] and prio.tolist() == [0.0]
    assert learner.health["rejected_batches"] == 1

    metrics, rows, _ = learner.train_step(with_labels(arrays(3)))  # in-range labels train
    assert metrics["skipped_nonfinite"] == 0 and learner.step == 1 and len(rows) == 3


def test_labels_for_another_depth_count_reject_the_batch(learner):
    a = with_labels(arrays(2))
    a["extra_voxel_indices"] = a["extra_voxel_indices"][:, :1]  # D = 1 for a 2-depth cascade
    metrics, rows, _ = learner.train_step(a)
    assert metrics == {} and rows.tolist() == [0, 1]


def with_n_step(a, steps=(1, 2, 3)):
    """n-step fields as a replay with ``n_step=3`` serves them."""
    a["n_rewards"] = np.zeros((len(a["indices"]), 3), np.float32)
    a["bootstrap_steps"] = np.array(steps, np.int64)
    return a


@pytest.mark.parametrize("steps, bad_rows", [((1, 0, 3), [1]), ((4, 2, 3), [0])])
def test_n_step_fields_that_describe_no_transition_are_rejected(learner, steps, bad_rows):
    metrics, rows, prio = learner.train_step(with_n_step(arrays(3), steps))
    assert metrics == {} and rows.tolist() == bad_rows and prio.tolist() == [0.0]

    a = with_n_step(arrays(3))
    del a["bootstrap_steps"]  # rewards without their step counts: every row is suspect
    assert learner.train_step(a)[1].tolist() == [0, 1, 2]

    metrics, rows, _ = learner.train_step(with_n_step(arrays(3)))  # well-formed n-step rows train
    assert metrics["skipped_nonfinite"] == 0 and learner.step == 1 and len(rows) == 3


def test_the_learner_counts_skipped_updates(learner):
    a = arrays(2)
    a["gripper_pose"][0, :3] = 3e38  # finite, but the network's output overflows
    a["gripper_pose_tp1"][0, :3] = 3e38
    metrics, rows, prio = learner.train_step(a)
    assert metrics["skipped_nonfinite"] == 1 and learner.health["skipped_updates"] == 1
    assert np.isfinite(prio).all() and len(rows) == 2
    assert learner.counters()["skipped_updates"] == 1 and "loss/depth0" not in learner.counters()


def test_the_learner_never_checkpoints_a_non_finite_state(learner):
    assert learner.checkpoint()
    [good] = complete_checkpoints(learner.checkpoint_dir)
    with torch.no_grad():
        next(learner.agent.nets.parameters())[0] = float("nan")
    learner.step = 5
    assert not learner.checkpoint() and learner.health["checkpoints_refused"] == 1
    assert complete_checkpoints(learner.checkpoint_dir) == [good]  # the previous one stays the latest
