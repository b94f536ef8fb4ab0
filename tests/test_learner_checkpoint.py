"""Learner checkpoints: atomic, pickle-free, and a resumed state is exactly the saved one."""

import torch

from learner.checkpoint import MARKER, complete_checkpoints, load_latest, save_checkpoint


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
