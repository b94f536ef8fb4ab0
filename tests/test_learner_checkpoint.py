"""Learner checkpoints: atomic, pickle-free, never non-finite, and a resumed state is exactly the saved one."""

import pytest
import torch
from safetensors.torch import save_file
from test_acting_average import TINY, batch

from learner.checkpoint import MARKER, NonFiniteState, complete_checkpoints, load_latest, save_checkpoint
from learner.config import LearnerConfig
from learner.train import Learner
from protocol.role import RoleContext


def _state(step: int) -> dict:
    net = torch.nn.Linear(4, 3)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    net(torch.randn(2, 4)).sum().backward()
    opt.step()
    return {"net": net.state_dict(), "optim": opt.state_dict(), "step": step, "rng": torch.get_rng_state()}


def test_round_trip_keeps_tensors_and_nested_optimiser_state(tmp_path):
    state = _state(7)
    save_checkpoint(tmp_path, 7, state)
    loaded = load_latest(tmp_path)
    assert loaded["step"] == 7
    for name, tensor in state["net"].items():
        assert torch.equal(loaded["net"][name], tensor)
    assert set(loaded["optim"]["state"]) == set(state["optim"]["state"])  # integer keys survive JSON
    assert torch.equal(loaded["optim"]["state"][0]["exp_avg"], state["optim"]["state"][0]["exp_avg"])
    assert loaded["optim"]["param_groups"][0]["lr"] == 1e-3
    assert torch.equal(loaded["rng"], state["rng"])


def test_only_complete_checkpoints_count_and_old_ones_are_pruned(tmp_path):
    for step in (1, 2, 3):
        save_checkpoint(tmp_path, step, _state(step), keep=2)
    assert [p.name for p in complete_checkpoints(tmp_path)] == ["step-000000002", "step-000000003"]
    # A checkpoint that died before its marker was written is ignored.
    (tmp_path / "step-000000009").mkdir()
    (tmp_path / "step-000000003" / MARKER).unlink()
    assert load_latest(tmp_path)["step"] == 2


def test_no_checkpoint_means_a_fresh_start(tmp_path):
    assert load_latest(tmp_path / "missing") is None


def test_a_non_finite_state_is_refused_and_the_previous_checkpoint_kept(tmp_path):
    save_checkpoint(tmp_path, 1, _state(1))
    for poison in ({"x": torch.tensor([1.0, float("inf")])}, {"x": torch.ones(1), "loss": float("nan")}):
        with pytest.raises(NonFiniteState):
            save_checkpoint(tmp_path, 2, poison)
    assert [p.name for p in complete_checkpoints(tmp_path)] == ["step-000000001"]
    assert not list(tmp_path.glob(".tmp-*"))


def test_a_poisoned_or_unreadable_checkpoint_is_skipped_for_the_previous_one(tmp_path):
    save_checkpoint(tmp_path, 1, {"w": torch.ones(2), "step": 1}, keep=3)
    poisoned = save_checkpoint(tmp_path, 2, {"w": torch.ones(2), "step": 2}, keep=3)
    broken = save_checkpoint(tmp_path, 3, {"w": torch.ones(2), "step": 3}, keep=3)
    # e.g. written before checkpoints were checked, or cut short by a failing disk
    save_file({"w": torch.tensor([1.0, float("nan")])}, str(poisoned / "tensors.safetensors"))
    (broken / "tensors.safetensors").write_bytes(b"not safetensors")
    assert load_latest(tmp_path)["step"] == 1


def test_a_slow_learner_checkpoints_by_time_as_well_as_by_step(tmp_path):
    """A killed learner loses at most ``checkpoint_every`` updates or ``checkpoint_every_s`` seconds of training."""
    learner = Learner(LearnerConfig(device="cpu", checkpoint_every=100, checkpoint_every_s=60.0), TINY,
                      RoleContext("run-1", "learner", tmp_path))
    start = learner.checkpointed_at
    learner.train_step(batch(0))
    assert not learner.checkpoint_due(start + 30)  # 1 update, 30 s: not yet
    assert learner.checkpoint_due(start + 61)  # a minute since the start: write one
    assert learner.checkpoint()
    assert not learner.checkpoint_due(learner.checkpointed_at + 30)  # the clock restarts at each checkpoint
    by_steps = Learner(LearnerConfig(device="cpu", checkpoint_every=1, checkpoint_every_s=0.0), TINY,
                       RoleContext("run-1", "learner", tmp_path / "b"))
    by_steps.train_step(batch(1))
    assert by_steps.checkpoint_due(by_steps.checkpointed_at + 10**6) and by_steps.step == 1
