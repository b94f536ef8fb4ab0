"""The typed config: presets, strict keys and types, overrides, and the run directory."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from typing import Literal, Optional

import pytest
import yaml
from conftest import REPO

from actors.config import ActorConfig
from deploy.cli import build_parser, overrides_from_args
from deploy.config import RunConfig, dump_yaml, load_config, write_run_dir
from deploy.config_loader import ConfigError, field_docs, from_dict, parse_override, to_dict


@dataclass
class Inner:
    mode: Literal["fast", "slow"] = "fast"  #: a choice
    ratio: float = 0.5  #: a float


@dataclass
class Outer:
    count: int = 1  #: an int
    name: Optional[str] = None  #: an optional string
    sizes: list[int] = field(default_factory=list)  #: a list
    bounds: tuple[float, ...] = (0.0, 1.0)  #: a tuple
    pair: tuple[int, str] = (1, "a")  #: a fixed tuple
    either: float | tuple[float, ...] = 0.1  #: a union
    on: bool = False  #: a bool
    inner: Inner = field(default_factory=Inner)  #: a nested section


def test_loader_builds_nested_dataclasses_from_plain_data():
    cfg = from_dict(Outer, {"count": 3, "name": "x", "sizes": [1, 2], "bounds": [0, 2.5], "pair": [2, "b"],
                            "either": [1, 2], "on": True, "inner": {"mode": "slow", "ratio": 1}})
    assert cfg == Outer(3, "x", [1, 2], (0.0, 2.5), (2, "b"), (1.0, 2.0), True, Inner("slow", 1.0))
    assert from_dict(Outer, {}) == Outer()
    assert from_dict(Outer, to_dict(cfg)) == cfg


@pytest.mark.parametrize(
    "data, message",
    [
        ({"cuont": 1}, "cuont: unknown key (did you mean 'count'?)"),
        ({"inner": {"mdoe": "fast"}}, "inner.mdoe: unknown key (did you mean 'mode'?)"),
        ({"count": "lots"}, "count: expected int, got 'lots'"),
        ({"count": True}, "count: expected int, got True"),
        ({"on": "yes please"}, "on: expected bool"),
        ({"inner": {"mode": "medium"}}, "inner.mode: expected one of 'fast', 'slow', got 'medium'"),
        ({"sizes": [1, "two"]}, "sizes[1]: expected int, got 'two'"),
        ({"pair": [1]}, "pair: expected 2 items, got 1"),
        ({"inner": 3}, "inner: expected a mapping"),
        ({"either": "wide"}, "either: expected float or tuple"),
    ],
)
def test_loader_rejects_bad_keys_and_values_naming_them(data, message):
    with pytest.raises(ConfigError) as err:
        from_dict(Outer, data)
    assert message in str(err.value)


def test_overrides_parse_values_as_yaml_scalars():
    assert parse_override("replay.capacity_transitions=1000") == {"replay": {"capacity_transitions": 1000}}
    assert parse_override("fabric.connect=[tcp/10.0.0.2:7447]") == {"fabric": {"connect": ["tcp/10.0.0.2:7447"]}}
    assert parse_override("fabric.shared_memory=false") == {"fabric": {"shared_memory": False}}
    assert parse_override("run.run_id=exp-1") == {"run": {"run_id": "exp-1"}}
    with pytest.raises(ConfigError, match="expected section.key=value"):
        parse_override("replay.capacity_transitions")


@pytest.mark.parametrize("preset", ["cpu-small", "paper"])
def test_presets_load_and_apply_what_they_name(preset):
    cfg = load_config(preset)
    written = yaml.safe_load((REPO / "configs" / f"{preset}.yaml").read_text())
    for section, values in written.items():
        for key, value in values.items():
            assert to_dict(getattr(getattr(cfg, section), key)) == value


def test_resolution_order_defaults_preset_file_flags_set(tmp_path):
    extra = tmp_path / "extra.yaml"
    extra.write_text("launch: {num_actors: 5}\nreplay: {zstd_level: 3}\n")
    args = build_parser().parse_args(
        ["launch", "--config", str(extra), "--actors", "7", "--router-port", "9000", "--set", "replay.zstd_level=4",
         "--run-id", "exp-1", "--no-shm"]
    )
    cfg = load_config(args.preset, files=tuple(args.config), overrides=tuple(overrides_from_args(args)))
    assert cfg.launch.num_actors == 7  # flag beats file
    assert cfg.replay.zstd_level == 4  # --set beats file
    assert cfg.replay.min_size_to_sample == 200  # from the cpu-small preset
    assert cfg.fabric.listen == cfg.fabric.connect == ["tcp/127.0.0.1:9000"]
    assert cfg.fabric.shared_memory is False
    assert cfg.run.run_id == "exp-1"


def test_listening_on_all_interfaces_makes_local_roles_dial_loopback():
    args = build_parser().parse_args(["router", "--listen", "tcp/0.0.0.0:7447", "--run-id", "r", "--certs", "keys"])
    cfg = load_config(None, overrides=tuple(overrides_from_args(args)))
    assert cfg.fabric.listen == ["tcp/0.0.0.0:7447"] and cfg.fabric.connect == ["tcp/127.0.0.1:7447"]
    assert cfg.fabric.endpoints("listen") == ["tls/0.0.0.0:7447"]  # with keys, every link is TLS
    insecure = build_parser().parse_args(["router", "--listen", "tcp/0.0.0.0:7447", "--run-id", "r", "--insecure"])
    assert load_config(None, overrides=tuple(overrides_from_args(insecure))).fabric.insecure
    bare = build_parser().parse_args(["router", "--listen", "tcp/0.0.0.0:7447", "--run-id", "r"])
    with pytest.raises(ConfigError, match="fabric.listen tcp/0.0.0.0:7447 is beyond loopback: pass --certs DIR"):
        load_config(None, overrides=tuple(overrides_from_args(bare)))


def test_bad_values_are_rejected_with_their_path():
    for override, message in [
        ({"launch": {"roles": ["router", "trainer"]}}, "launch: unknown role 'trainer'"),
        ({"dashboard": {"port": 70000}}, r"dashboard.port must be in 0..65535 \(got 70000\)"),
        ({"run": {"run_id": "a/b"}}, "run: invalid run id 'a/b'"),
        ({"replay": {"compression": "gzip"}}, "replay.compression: expected one of"),
        ({"launch": {"roles": ["replay", "robot"]}}, "actor.scene_bounds_on_wire: must be true in a run with a robot"),
    ]:
        with pytest.raises(ConfigError, match=message):
            load_config(None, overrides=(override,))


@pytest.mark.parametrize(
    "override, message",
    [
        ("learner.batch_size=-3", "learner.batch_size must be >= 1 (got -3)"),
        ("learner.batch_size=0", "learner.batch_size must be >= 1 (got 0)"),
        ("learner.prefetch=0", "learner.prefetch must be >= 1"),
        ("learner.publish_every=0", "learner.publish_every must be >= 1"),
        ("learner.checkpoint_keep=0", "learner.checkpoint_keep must be >= 1"),
        ("learner.max_updates=-1", "learner.max_updates must be >= 0"),
        ("learner.sample_timeout_s=.nan", "learner.sample_timeout_s must be finite and > 0 (got nan)"),
        ("learner.acting_average=1.0", "learner.acting_average must be in [0, 1) (got 1.0)"),
        ("learner.device=cdua", "learner.device must be auto, cpu, mps, cuda or cuda:N"),
        ("learner.replay_endpoint=tcp://127.0.0.1:0", "learner.replay_endpoint must be tcp://HOST:PORT"),
        ("learner.batch_size=1000", "learner.batch_size must be <= replay.max_batch_size (512)"),
        ("qattention.lr=nan", "qattention.lr must be finite and > 0 (got nan)"),
        ("qattention.lr=.inf", "qattention.lr must be finite and > 0 (got inf)"),
        ("qattention.lr=0", "qattention.lr must be > 0 (got 0.0)"),
        ("qattention.gamma=1.5", "qattention.gamma must be in [0, 1] (got 1.5)"),
        ("qattention.tau=0", "qattention.tau must be in (0, 1]"),
        ("qattention.voxel_size=6", "qattention.voxel_size must be a power of two >= 4 (got 6)"),
        ("qattention.rotation_resolution=0", "qattention.rotation_resolution must be in 1..360 (got 0)"),
        ("qattention.rotation_resolution=7", "qattention.rotation_resolution must divide 360 (got 7)"),
        ("qattention.depths=0", "qattention.depths must be >= 1"),
        ("qattention.bounds_offset=[0.15, -0.1]", "qattention.bounds_offset[1] must be > 0 (got -0.1)"),
        ("qattention.per_alpha=-0.1", "qattention.per_alpha must be in [0, 1]"),
        ("qattention.crop_shift=2", "qattention.crop_shift must be in [0, 1]"),
        ("replay.capacity_transitions=0", "replay.capacity_transitions must be >= 1 (got 0)"),
        ("replay.importance_beta=2", "replay.importance_beta must be in [0, 1]"),
        ("replay.priority_eps=0", "replay.priority_eps must be > 0"),
        ("replay.zstd_level=30", "replay.zstd_level must be in -131072..22 (got 30)"),
        ("replay.sample_wait_timeout_s=0", "replay.sample_wait_timeout_s must be > 0"),
        ("replay.zmq_endpoint=tcp://127.0.0.1:99999", "replay.zmq_endpoint must be tcp://HOST:PORT (port 1-65535)"),
        ("replay.min_size_to_sample=30000", "replay.min_size_to_sample must be <= replay.capacity_transitions (20000)"),
        (("replay.samples_per_insert=2", "replay.samples_per_insert_error_buffer=1.5"),
         "replay.samples_per_insert_error_buffer must be >= max(1, samples_per_insert) = 2"),
        (("replay.samples_per_insert=2", "replay.samples_per_insert_error_buffer=4"),
         "replay.samples_per_insert_error_buffer must be >= learner.batch_size (8)"),
        ("actor.epsilon=1.5", "actor.epsilon must be in [0, 1] (got 1.5)"),
        ("actor.outbox_size=0", "actor.outbox_size must be >= 1"),
        ("actor.resend_after_s=0", "actor.resend_after_s must be > 0"),
        ("actor.eval_every_versions=0", "actor.eval_every_versions must be >= 1"),
        ("sim.image_size=0", "sim.image_size must be >= 8 (got 0)"),
        ("sim.episode_length=0", "sim.episode_length must be >= 1"),
        ("sim.velocity_scale=1.5", "sim.velocity_scale must be in (0, 1]"),
        ("sim.planner=Foo", "sim.planner must be one of 'RRTConnect'"),
        ("sim.cameras=[front, front]", "sim.cameras must not repeat an entry"),
        ("sim.cameras=[]", "sim.cameras must name at least one camera"),
        ("sim.control_hz=500", "sim.physics_hz must be >= control_hz (500)"),
        ("sim.unreachable_reward=.nan", "sim.unreachable_reward must be a finite number (got nan)"),
        ("robot.verdict_wait_s=0", "robot.verdict_wait_s must be > 0"),
        ("robot.franka.gripper_force=0", "robot.franka.gripper_force must be > 0"),
        ("robot.safety.table_height=.nan", "robot.safety.table_height must be a finite number"),
        ("robot.cameras=[{name: top}]", "robot.cameras[0].name must be one of 'front'"),
        ("dashboard.port=-1", "dashboard.port must be in 0..65535 (got -1)"),
        ("dashboard.host=''", "dashboard.host must not be empty"),
        ("dashboard.refresh_ms=10", "dashboard.refresh_ms must be >= 100"),
        ("fabric.connect=[tcp/127.0.0.1:0]", "fabric.connect[0] must be tcp/HOST:PORT with port 1-65535"),
        ("fabric.listen=[tcp/127.0.0.1:70000]", "fabric.listen[0] must be tcp/HOST:PORT with port 0-65535"),
        ("fabric.connect=[]", "fabric.connect must name at least one endpoint"),
        ("fabric.reconnect_max_ms=10", "fabric.reconnect_max_ms must be >= 100"),
        ("launch.num_actors=-1", "launch.num_actors must be >= 0 (got -1)"),
        ("launch.roles=[]", "launch.roles must not be empty"),
        ("launch.shutdown_grace_s=0", "launch.shutdown_grace_s must be in (0, 60]"),
        ("launch.router_wait_s=0", "launch.router_wait_s must be > 0"),
        ("launch.liveness_timeout_s=.inf", "launch.liveness_timeout_s must be finite and >= 0"),
        ("launch.instance_prefix=a/b", "launch.instance_prefix must start with a letter or digit"),
        ("run.seed=-1", "run.seed must be >= 0 (got -1)"),
        ("run.runs_dir=''", "run.runs_dir must not be empty"),
        ("demos.episodes=-1", "demos.episodes must be >= 0"),
        ("demos.every_n=0", "demos.every_n must be >= 1 (got 0)"),
        ("demos.chain_keyframes=-1", "demos.chain_keyframes must be >= 0 (got -1)"),
        ("replay.curve_certificate=/keys/replay.key_secret",
         "replay.curve_clients must be set too when curve_certificate is"),
        ("learner.curve_server_key=/keys/replay.key",
         "learner.curve_certificate must be set too when curve_server_key is"),
        ("learner.zmq_io_threads=0", "learner.zmq_io_threads must be >= 1"),
        ("replay.zmq_io_threads=0", "replay.zmq_io_threads must be >= 1"),
    ],
)
def test_every_field_out_of_its_range_is_one_config_error_naming_it(override, message):
    """`--set section.key=value` out of range: resolving the config (what every command does
    before it starts anything) raises one line naming the dotted field and its allowed range."""
    sets = [override] if isinstance(override, str) else list(override)  # a rule across two fields: two --set
    args = build_parser().parse_args(["launch", *(arg for text in sets for arg in ("--set", text))])
    with pytest.raises(ConfigError) as err:
        load_config(args.preset, files=tuple(args.config), overrides=tuple(overrides_from_args(args)))
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_curve_key_files_are_checked_when_the_config_is_resolved(tmp_path):
    """Each CURVE key path must name a file that loads (secrets private), in one line naming the field."""
    import os
    import shutil

    import zmq.auth

    for name in ("replay", "learner"):
        os.chmod(zmq.auth.create_certificates(tmp_path, name)[1], 0o600)
    (tmp_path / "clients").mkdir()
    shutil.copy(tmp_path / "learner.key", tmp_path / "clients")
    good = {"replay": {"curve_certificate": str(tmp_path / "replay.key_secret"),
                       "curve_clients": str(tmp_path / "clients")},
            "learner": {"curve_certificate": str(tmp_path / "learner.key_secret"),
                        "curve_server_key": str(tmp_path / "replay.key")}}
    cfg = load_config(None, overrides=(good,))
    assert cfg.learner.curve_server_key.endswith("replay.key") and cfg.replay.curve_clients.endswith("clients")
    (tmp_path / "garbage.key_secret").write_text("not a certificate\n")
    os.chmod(tmp_path / "garbage.key_secret", 0o600)
    (tmp_path / "short.key").write_text('curve\n    public-key = "tooshort"\n')
    (tmp_path / "empty").mkdir()
    shutil.copy(tmp_path / "learner.key_secret", tmp_path / "shared.key_secret")
    os.chmod(tmp_path / "shared.key_secret", 0o644)
    for section, key, value, message in [
        ("learner", "curve_certificate", tmp_path / "missing.key_secret",
         "learner.curve_certificate must be a readable CURVE key file ({}: no such file)"),
        ("learner", "curve_certificate", tmp_path / "learner.key", "holds no secret key"),
        ("learner", "curve_certificate", tmp_path / "garbage.key_secret", "holds no public key"),
        ("learner", "curve_certificate", tmp_path / "shared.key_secret", "others may access it (mode 0644): chmod 600"),
        ("learner", "curve_server_key", tmp_path / "short.key", "malformed public key"),
        ("learner", "curve_server_key", tmp_path / "replay.key_secret", "holds a secret key: give the peer's public"),
        ("replay", "curve_clients", tmp_path / "empty", "holds no public NAME.key file"),
        ("replay", "curve_clients", tmp_path / "learner.key", "not a directory"),
    ]:
        bad = {section: {**good[section], key: str(value)}}
        with pytest.raises(ConfigError) as err:
            load_config(None, overrides=(bad,))
        assert message.format(value) in str(err.value) and str(err.value).startswith(f"{section}.{key} ")
        assert "\n" not in str(err.value)


def test_every_shipped_preset_resolves_within_range():
    presets = sorted(p.stem for p in (REPO / "configs").glob("*.yaml"))
    assert {"cpu-small", "paper", "robot"} <= set(presets)
    for preset in presets:
        load_config(preset)  # raises ConfigError if any value is out of its range
    load_config(None)  # the bare defaults too


def test_the_sim_planner_names_match_the_motion_planner():
    from actors.control.planner import PLANNERS
    from actors.sim.config import PLANNERS as CONFIGURABLE

    assert CONFIGURABLE == PLANNERS


def test_cli_refuses_an_out_of_range_value_before_starting_anything(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "launch", "--runs-dir", str(tmp_path), "--router-port", "0",
         "--dashboard-port", "0", "--set", "learner.batch_size=-3"],
        capture_output=True, text=True, cwd=REPO, timeout=60,
    )
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "learner.batch_size must be >= 1 (got -3)" in lines[0], result.stderr
    assert not any(tmp_path.iterdir())  # no run directory: nothing was started
    assert result.stdout == ""  # the launcher never announced a run


def test_a_bad_preset_file_is_named(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("replay:\n  capasity: 3\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: replay.capasity: unknown key"):
        load_config(str(bad))
    with pytest.raises(ConfigError, match="preset 'nope' not found"):
        load_config("nope")


def test_the_run_directory_holds_the_resolved_config_and_versions(tmp_path):
    cfg = load_config("cpu-small", overrides=({"run": {"run_id": "exp-2", "runs_dir": str(tmp_path)}},))
    run_dir = write_run_dir(cfg)
    assert run_dir == tmp_path / "exp-2"
    again = load_config(None, files=(run_dir / "config.yaml",))
    assert again == cfg
    versions = json.loads((run_dir / "versions.json").read_text())
    for name in ("python", "torch", "zenoh", "pybullet", "ompl", "numpy", "git_commit"):
        assert name in versions
    assert versions["zenoh"].startswith("1.")
    # the CPU too: hosts of one model name differ several-fold in learner speed (AVX2 only vs AVX-512-bf16)
    assert f", {os.cpu_count()} cores" in versions["cpu"]


def test_a_run_resumes_only_on_the_task_and_scene_revision_it_started_on(tmp_path, monkeypatch):
    """Its checkpoints hold that scene's replay and weights; a revised task needs a new run id."""
    from actors.sim import task_specs
    from deploy.preflight import problems

    cfg = load_config("cpu-small", overrides=({"run": {"run_id": "exp-3", "runs_dir": str(tmp_path)},
                                               "sim": {"task": "stack_wine"}},))
    run_dir = write_run_dir(cfg)
    assert json.loads((run_dir / "task.json").read_text()) == {
        "task": "stack_wine", "revision": task_specs.task_spec("stack_wine").revision}
    assert problems(cfg, ["learner"]) == []  # the same scene resumes

    revised = dataclasses.replace(task_specs.TASK_SPECS["stack_wine"], revision=99)
    monkeypatch.setitem(task_specs.TASK_SPECS, "stack_wine", revised)
    [problem] = problems(cfg, ["learner"])
    assert problem.startswith("run.run_id:") and "revision 99" in problem and "choose a new --run-id" in problem
    monkeypatch.undo()

    other = load_config(None, files=(run_dir / "config.yaml",), overrides=({"sim": {"task": "reach_target"}},))
    [problem] = problems(other, ["learner"])
    assert "holds a run of stack_wine revision" in problem and "not reach_target" in problem
    write_run_dir(cfg)  # a relaunch rewrites config.yaml but never the record of where the run began
    assert json.loads((run_dir / "task.json").read_text())["task"] == "stack_wine"


def test_every_config_field_has_a_doc_comment():
    cfg = RunConfig()
    sections = [RunConfig] + [type(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)]
    for cls in sections:
        docs = field_docs(cls)
        missing = [f.name for f in dataclasses.fields(cls) if not docs.get(f.name)]
        assert not missing, f"{cls.__name__}: fields without a doc comment: {missing}"
    documented = dump_yaml(cfg, docs=True)
    assert "capacity_transitions:" in documented and "#" in documented


def test_cli_rejects_a_bad_key_at_start_and_names_it(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "launch", "--runs-dir", str(tmp_path), "--set", "replay.capasity=10"],
        capture_output=True, text=True, cwd=REPO, timeout=60,
    )
    assert result.returncode == 2
    assert "replay.capasity: unknown key" in result.stderr
    assert not any(tmp_path.iterdir())  # nothing started, nothing written


def test_cli_prints_the_resolved_documented_config():
    result = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "launch", "--preset", "paper", "--run-id", "x", "--print-config"],
        capture_output=True, text=True, cwd=REPO, timeout=60,
    )
    assert result.returncode == 0, result.stderr
    printed = yaml.safe_load(result.stdout)
    assert printed["replay"]["capacity_transitions"] == 100000
    assert printed["run"]["run_id"] == "x"


def test_reading_the_config_does_not_load_torch():
    """The replay server, router and dashboard resolve the same config as the learner, but
    never run a network: torch's import (seconds, hundreds of MB each) stays out of them."""
    code = "import sys, deploy.config, replay_server.service, dashboard.app; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", out.stderr


def test_epsilon_decays_linearly_over_learner_updates_then_stays_at_its_floor():
    decaying = ActorConfig(epsilon=0.3, epsilon_final=0.05, epsilon_decay_updates=100)
    assert [round(decaying.epsilon_at(step), 4) for step in (0, 50, 100, 10_000)] == [0.3, 0.175, 0.05, 0.05]
    assert ActorConfig(epsilon=0.3).epsilon_at(10_000) == 0.3  # no decay asked: constant, as before
    with pytest.raises(ValueError, match="epsilon"):
        ActorConfig(epsilon_final=1.5)
