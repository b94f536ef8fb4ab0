"""A portable policy: export a run's trained networks, evaluate them with no run, relaunch a run from its config.

The run here is real but small: a learner (tiny networks) trained on a few synthetic batches
checkpoints into a run directory whose config.yaml the launcher's own code wrote.
"""

from __future__ import annotations

import contextlib
import json
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import REPO, get_free_port
from conftest import run_c2farm as c2farm
from safetensors import safe_open

from deploy import config as cfg_mod
from deploy.roles import network_config
from learner.config import LearnerConfig
from learner.train import Learner
from protocol.policy_file import CONFIG, MODEL, read_policy
from protocol.role import RoleContext
from qattention.synthetic import transition_arrays

#: networks small enough to train and act in seconds
TINY = ["--set", "qattention.voxel_size=8", "--set", "qattention.kernels=4", "--set", "qattention.head_width=16",
        "--set", "qattention.image_crop=16", "--set", "qattention.rotation_resolution=30",
        "--set", "qattention.bf16=false", "--set", "sim.image_size=64"]
SUCCESS_LINE = re.compile(r"^success (\d+)/2 \((\d+) %\) over 2 episodes of reach_target, "
                          r"policy v(\d+) \(learner step (\d+)\)$", re.M)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, Learner]:
    """A run directory with config.yaml and a learner checkpoint after 3 updates."""
    runs = tmp_path_factory.mktemp("runs")
    config = cfg_mod.load_config(overrides=({"run": {"run_id": "exp1", "runs_dir": str(runs)},
                                             "sim": {"task": "reach_target", "image_size": 64},
                                             "qattention": {"voxel_size": 8, "kernels": 4, "head_width": 16,
                                                            "image_crop": 16, "rotation_resolution": 30,
                                                            "bf16": False}},))
    run_dir = cfg_mod.write_run_dir(config)
    qconfig = network_config(config)
    learner = Learner(LearnerConfig(device="cpu", publish_every=1), qconfig, RoleContext("exp1", "learner", run_dir))
    for seed in range(3):
        arrays = transition_arrays(2, cameras=qconfig.cameras, resolution=32, seed=seed,
                                   scene_bounds=qconfig.scene_bounds)
        arrays["indices"] = arrays["keys"] = np.arange(2, dtype=np.int64)
        metrics, _, _ = learner.train_step(arrays)
        assert metrics, "the synthetic batch was rejected"
        learner.version += 1  # as publish() would, without a fabric
    assert learner.checkpoint()
    return run_dir, learner


@pytest.fixture(scope="module")
def exported(trained, tmp_path_factory) -> Path:
    run_dir, _ = trained
    out = tmp_path_factory.mktemp("policy")
    code, stdout, stderr = c2farm("export", "policy", str(run_dir), "--out", str(out))
    assert code == 0, stderr
    assert "policy v3 (learner step 3) of reach_target" in stdout
    return out


def test_the_policy_holds_exactly_the_online_networks_and_what_acting_needs(trained, exported):
    _, learner = trained
    online = learner.agent.weights()
    with safe_open(str(exported / MODEL), framework="pt") as f:
        assert sorted(f.keys()) == sorted(online)  # no target networks, no optimiser moments
    policy = read_policy(exported)
    for name, tensor in online.items():
        assert policy.tensors[name].dtype == tensor.dtype and torch.equal(policy.tensors[name], tensor), name
    config = json.loads((exported / CONFIG).read_text())
    assert config["task"] == "reach_target" and config["cameras"] == list(learner.qconfig.cameras)
    assert config["scene_bounds"] == list(learner.qconfig.scene_bounds)
    assert config["qattention"]["kernels"] == 4 and config["qattention"]["voxel_size"] == 8
    assert (config["weights_version"], config["learner_step"], config["weights"]) == (3, 3, "online")
    assert {"c2farm", "git_commit"} <= config["code"].keys() and config["code"]["c2farm"]
    assert config["sim"]["image_size"] == 64 and config["run_id"] == "exp1"


def test_a_named_checkpoint_exports_the_same_policy(trained, tmp_path):
    run_dir, _ = trained
    (step,) = sorted((run_dir / "checkpoints" / "learner").glob("step-*"))
    code, _, stderr = c2farm("export", "policy", str(run_dir), "--out", str(tmp_path),
                             "--checkpoint", str(step / "tensors.safetensors"))
    assert code == 0, stderr
    assert read_policy(tmp_path).learner_step == 3


def test_eval_runs_an_exported_policy_with_no_run_and_no_router(exported, tmp_path):
    """`python -m c2farm` is the console script; in an empty folder, nothing else running."""
    done = subprocess.run([sys.executable, "-m", "c2farm", "eval", "--policy", str(exported), "--task",
                           "reach_target", "--episodes", "2"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    match = SUCCESS_LINE.search(done.stdout)
    assert match, done.stdout
    successes, percent, version, step = map(int, match.groups())
    assert successes <= 2 and percent == round(50 * successes) and (version, step) == (3, 3)
    assert not any(tmp_path.iterdir())  # no run directory, no demos: it joined nothing


def test_eval_with_foxglove_serves_the_scene_live_while_it_evaluates(exported, tmp_path):
    """`--foxglove 0`: the evaluator logs its WebSocket address; a Foxglove client connected there sees channels."""
    from websockets.sync.client import connect

    proc = subprocess.Popen([sys.executable, "-m", "c2farm", "eval", "--policy", str(exported), "--task",
                             "reach_target", "--episodes", "5", "--foxglove", "0"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        address = None
        for line in proc.stdout:
            if found := re.search(r"ws://127\.0\.0\.1:\d+", line):
                address = found.group(0)
                break
        assert address, "the evaluator never logged its live view's address"
        with connect(address, subprotocols=["foxglove.sdk.v1"], open_timeout=30) as ws:
            ops = []
            while "advertise" not in ops:
                message = ws.recv(timeout=120)
                if isinstance(message, str):
                    ops.append(json.loads(message)["op"])
        assert ops[0] == "serverInfo"
        assert proc.wait(timeout=600) == 0
    finally:
        proc.kill()
        proc.wait()


def _break(policy: Path, how: str) -> None:
    if how == "no model":
        (policy / MODEL).unlink()
    elif how == "corrupt model":
        (policy / MODEL).write_bytes(b"\x08\x00\x00\x00\x00\x00\x00\x00{}garbage")
    elif how == "config not json":
        (policy / CONFIG).write_text("{not json")
    elif how == "config lacks a field":
        config = json.loads((policy / CONFIG).read_text())
        del config["weights_version"]
        (policy / CONFIG).write_text(json.dumps(config))
    elif how == "network of another shape":
        config = json.loads((policy / CONFIG).read_text())
        config["qattention"]["kernels"] = 8
        (policy / CONFIG).write_text(json.dumps(config))


@pytest.mark.parametrize("how", ["no folder", "no model", "corrupt model", "config not json", "config lacks a field",
                                 "network of another shape"])
def test_a_bad_policy_folder_is_one_line_and_exit_2(exported, tmp_path, how):
    policy = tmp_path / "policy"
    if how != "no folder":
        policy.mkdir()
        for name in (MODEL, CONFIG):
            (policy / name).write_bytes((exported / name).read_bytes())
        _break(policy, how)
    code, stdout, stderr = c2farm("eval", "--policy", str(policy), "--episodes", "1")
    assert code == 2 and not stdout
    assert len(stderr.strip().splitlines()) == 1 and stderr.startswith("c2farm: eval --policy: "), stderr


def test_export_from_what_is_not_a_run_or_a_checkpoint_is_one_line_and_exit_2(trained, tmp_path):
    run_dir, _ = trained
    empty_run = tmp_path / "run"
    empty_run.mkdir()
    (empty_run / "config.yaml").write_text((run_dir / "config.yaml").read_text())
    garbage = tmp_path / "step-000000001"
    garbage.mkdir()
    (garbage / "COMPLETE").write_text("1")
    (garbage / "tensors.safetensors").write_bytes(b"junk")
    (garbage / "state.json").write_text("{}")
    for argv in ([str(tmp_path / "missing")], [str(empty_run)], [str(run_dir), "--checkpoint", str(garbage)],
                 [str(run_dir), "--checkpoint", str(tmp_path)]):
        code, stdout, stderr = c2farm("export", "policy", *argv, "--out", str(tmp_path / "out"))
        assert code == 2 and not stdout, argv
        assert len(stderr.strip().splitlines()) == 1 and stderr.startswith("c2farm: export policy: "), stderr
    assert not (tmp_path / "out").exists()


def test_python_dash_m_c2farm_is_the_console_script(tmp_path):
    done = subprocess.run([sys.executable, "-m", "c2farm", "--help"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and "usage: c2farm" in done.stdout, done.stderr


def test_a_runs_config_yaml_relaunches_it_exactly(tmp_path):
    """`c2farm launch --config runs/<id>/config.yaml` resolves the config the first launch did, key for key,
    whatever the preset under it: the file the launcher wrote holds every key."""
    flags = ["--run-id", "relaunch", "--runs-dir", str(tmp_path / "runs"), "--task", "push_button", "--seed", "7",
             "--preset", "paper", "--actors", "3", "--router-port", str(get_free_port()),
             "--dashboard-port", str(get_free_port()), "--roles", "router",
             "--set", "qattention.bounds_offset=[0.2]", "--set", "sim.episode_length=7", *TINY]
    launcher = subprocess.Popen([sys.executable, "-m", "c2farm", "launch", *flags], cwd=REPO,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    written = tmp_path / "runs" / "relaunch" / "config.yaml"
    try:
        deadline = time.monotonic() + 240
        while not written.exists() and launcher.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
        time.sleep(0.5)  # written in one call; let it finish
        assert written.exists(), launcher.stderr.read() if launcher.poll() is not None else "no config.yaml"
    finally:
        launcher.send_signal(signal.SIGTERM)
        launcher.wait(timeout=60)
    text = written.read_text()
    code, first, _ = c2farm("launch", *flags, "--print-config")
    assert code == 0
    for preset in ("cpu-small", "paper", "none"):
        code, again, stderr = c2farm("launch", "--config", str(written), "--preset", preset, "--print-config")
        assert code == 0, stderr
        assert again == first, preset
    assert written.read_text() == text


def test_the_robot_acts_greedily_with_an_exported_policy_watched_live_in_foxglove(exported, tmp_path):
    """`c2farm robot --policy --foxglove 0` on franky-sim, the scripted operator judging: the evaluation, with no
    run, while a Foxglove client sees the arm's camera and each decision's attention."""
    pytest.importorskip("franky")
    pytest.importorskip("franky_sim")
    from test_live_view import Client
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    proc = subprocess.Popen([sys.executable, "-m", "c2farm", "robot", "--policy", str(exported), "--robot",
                             "franky-sim", "--camera", "mujoco", "--set", "robot.scripted_operator=true", "--set",
                             "robot.franka.dynamics_factor=0.5", "--set", "robot.verdict_wait_s=1", "--episodes", "1",
                             "--foxglove", "0"], cwd=tmp_path, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []

    def read() -> None:  # drained as it comes, so the pipe never fills while the client listens
        for line in proc.stdout:
            lines.append(line)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        address = None
        deadline = time.monotonic() + 300
        while address is None and time.monotonic() < deadline and (proc.poll() is None or reader.is_alive()):
            address = next((f.group(0) for line in list(lines) if (f := re.search(r"ws://127\.0\.0\.1:\d+", line))),
                           None)
            time.sleep(0.05)
        assert address, "the robot never logged its live view's address:\n" + "".join(lines)[-2000:]
        wanted = {"/front/image", "/policy/attention"}
        with connect(address, subprotocols=["foxglove.sdk.v1"], open_timeout=30) as ws:
            client = Client(ws)
            with contextlib.suppress(ConnectionClosed):  # the server closes when the evaluation is done
                while not wanted <= client.received.keys() and time.monotonic() < deadline:
                    client.pump(1.0)
        assert wanted <= client.received.keys(), sorted(client.received)
        depths = cfg_mod.load_config().qattention.depths  # one entity per depth of the preset's grid
        assert [e.id for e in client.received["/policy/attention"][0].entities] == [f"depth{d}" for d in range(depths)]
        assert proc.wait(timeout=600) == 0, "".join(lines)[-2000:]
        reader.join(timeout=30)
        output = "".join(lines)
        assert re.search(r"^success [01]/1 \((0|100) %\) over 1 episode of reach_target, policy v3 "
                         r"\(learner step 3\)$", output, re.M), output[-2000:]
        assert not any(tmp_path.iterdir())
    finally:
        proc.kill()
        proc.wait()


def test_a_run_that_acted_with_an_average_exports_the_average(tmp_path):
    """With learner.acting_average the actors and the evaluator acted with an average: that is the policy."""
    from test_acting_average import TINY, batch

    from deploy.policy_export import acting_weights

    learner = Learner(LearnerConfig(device="cpu", acting_average=0.5), TINY, RoleContext("r", "learner", tmp_path))
    for seed in range(2):
        learner.train_step(batch(seed))
    acted = learner.acting.weights(learner.agent.weights())
    weights, source = acting_weights(learner.state(), 0.5)
    assert source == "acting_average" and all(torch.equal(weights[k], acted[k]) for k in acted)
    assert acting_weights(learner.state(), 0.0)[1] == "online"
