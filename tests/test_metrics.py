"""``/metrics`` is scrapeable: every counter the roles report is catalogued, and the real app's
answer, fed those counters, passes ``promtool check metrics`` (Debian's ``prometheus``).

The counter names come from the code, not from a list kept here: the replay server, the
learner, the outbox, the weights follower (and the robot actor's arm and operator channel) are
real objects (cheap, in-process); the heartbeat ``counters=`` closures inside the roles' ``run()``
functions (actor, robot, evaluator, demo source, dashboard) are read from their source with
``ast``, with the parts they splice in (``**outbox.counters``, ``**follower.counters()``, ...)
taken from those real objects. A new Heartbeat call, or a closure this reader cannot follow,
fails the test rather than passing unchecked.
"""

from __future__ import annotations

import ast
import functools
import logging
import math
import shutil
import subprocess
import threading
from pathlib import Path
from typing import Callable, Iterator

import httpx
import numpy as np
import pytest
import uvicorn
from conftest import REPO, get_free_port, wait_for

from dashboard.app import create_app
from dashboard.metrics import UNDOCUMENTED, prometheus_text
from dashboard.metrics_catalog import BY_LABEL, EXACT, Family, Skip, lookup
from dashboard.registry import RoleTable
from protocol import Status
from protocol.fabric import FabricConfig, open_session
from protocol.role import RoleContext

ROLE_PACKAGES = ("actors", "learner", "replay_server", "deploy", "dashboard")
BUILT_IN = {"c2farm_role_alive", "c2farm_role_last_seen_age_seconds", "c2farm_rejected_status_messages_total",
            UNDOCUMENTED}


# -- the counter names the code reports ----------------------------------------------------
def _replay_counters(session, tmp: Path) -> dict[str, float]:
    """A started replay service's status counters, with every by-reason counter fired once."""
    from replay_server.config import ReplayConfig
    from replay_server.rejections import ReasonCounter
    from replay_server.service import ReplayService

    config = ReplayConfig(zmq_endpoint=f"tcp://127.0.0.1:{get_free_port()}", checkpoint_interval_s=0,
                          checkpoint_on_stop=False, wal_fsync=False, checkpoint_dir=str(tmp / "replay"))
    service = ReplayService(config, RoleContext("run-1", "replay", tmp), session)
    service.start()
    try:
        for part in (service.ingest, service.sampler, service.checkpointer):
            for counter in vars(part).values():
                if isinstance(counter, ReasonCounter):  # a reason nobody listed, and an exception type
                    counter.count("unforeseen reason")
                    counter.error(OSError("disk full"))
        return service.counters()
    finally:
        service.close()


def _learner_counters(tmp: Path) -> dict[str, float]:
    """A learner's status counters after one real update (loss and Q per depth appear then)."""
    from learner.config import LearnerConfig
    from learner.train import Learner
    from qattention import QAttentionConfig
    from qattention.synthetic import transition_arrays

    tiny = QAttentionConfig(voxel_size=8, kernels=4, head_width=16, padding="zeros", image_crop=16,
                            rotation_resolution=30)
    learner = Learner(LearnerConfig(device="cpu"), tiny, RoleContext("run-1", "learner", tmp))
    batch = transition_arrays(2, resolution=32, seed=0)
    batch["indices"], batch["keys"] = np.arange(2, dtype=np.int64), np.arange(100, 102, dtype=np.int64)
    learner.train_step(batch)
    return learner.counters()


def _part_builders(session) -> dict[str, Callable[[], dict[str, float]]]:
    """What role closures splice in (``**outbox.counters``, ``**arm.safety.counters()``, ...), each
    from a real object with its by-reason counters fired, built when a closure names it."""

    def outbox() -> dict[str, float]:
        from protocol.episode_outbox import Outbox

        box = Outbox(session, "run-1", "actor-0")
        box.close()
        return dict(box.counters)

    def follower() -> dict[str, float]:
        from protocol.weights_follower import WeightsFollower

        weights = WeightsFollower(session, "run-1")
        weights.reject("unforeseen_reason")
        weights.close()
        return weights.counters()

    @functools.cache
    def arm():  # the robot actor's arm (actors/robot): built, never connected
        from actors.robot.config import FrankaConfig, SafetyConfig
        from actors.robot.franka import FrankaArm

        franka = FrankaArm(FrankaConfig(), SafetyConfig())
        franka.safety.check(np.full(7, np.nan), np.zeros(3))
        franka.safety.check(np.array([0.5, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0]), np.zeros(3))
        return franka

    def channel() -> dict[str, float]:
        from actors.robot.operator import OperatorChannel
        from protocol.messages import OperatorAction

        operator = OperatorChannel()
        for action in OperatorAction:
            operator.put(action, "test")
        return dict(operator.counters)

    def evaluation() -> dict[str, float]:  # the latest greedy evaluation (evaluator, robot actor)
        from actors.evaluation import EvalResult

        return EvalResult(5, 50, 300, 20, 0.9, 0.9, 0.05).counters()

    def stats() -> dict[str, float]:  # episodes an acting role collected (actors/role_loop.py)
        from actors.actor_loop import Rollout
        from actors.control import UNREACHABLE_REASONS
        from actors.role_loop import EpisodeStats

        counted = EpisodeStats()
        for reason in UNREACHABLE_REASONS:
            counted.add(Rollout(observations=[], reason="unreachable", unreachable_reason=reason))
        return counted.as_dict()

    parts = {"outbox": outbox, "follower": follower, "stats": stats, "arm": lambda: dict(arm().counters),
             "arm.safety": lambda: arm().safety.counters(), "channel": channel,
             "latest": evaluation}
    return {name: functools.cache(build) for name, build in parts.items()}


class _ClosureReader:
    """Counter names a ``counters=`` closure returns, read from source (see the module docstring).

    ``computed`` gives the values the code fills into an f-string key (``f"unreachable_{reason}"``).
    """

    def __init__(self, scope: ast.AST, shared: dict[str, Callable[[], dict[str, float]]],
                 computed: dict[str, tuple[str, ...]]):
        self.scope, self.shared, self.computed = scope, shared, computed
        self.unresolved: list[str] = []

    def names(self, node: ast.AST) -> set[str]:
        if isinstance(node, ast.Lambda):
            return self.names(node.body)
        if isinstance(node, ast.Dict):
            out: set[str] = set()
            for key, value in zip(node.keys, node.values):
                out |= self.names(value) if key is None else self._key(key)
            return out
        if isinstance(node, ast.Name):
            return self._local(node.id)
        if isinstance(node, ast.IfExp):  # ``x.counters() if x else {}``: either branch's names
            return self.names(node.body) | self.names(node.orelse)
        source = ast.unparse(node)
        for part, counters in self.shared.items():  # outbox.counters, follower.counters(), ...
            if source in (f"{part}.counters", f"{part}.counters()", f"{part}.as_dict()"):
                return set(counters())
        self.unresolved.append(source)
        return set()

    def _local(self, name: str) -> set[str]:
        """A nested def (what it returns) or a dict literal (its keys and every key stored into it)."""
        for node in ast.walk(self.scope):
            if isinstance(node, ast.FunctionDef) and node.name == name:
                return set().union(*(self.names(r.value) for r in ast.walk(node) if isinstance(r, ast.Return)))
        out: set[str] = set()
        assigned = False
        for node in ast.walk(self.scope):
            if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == name for t in node.targets):
                assigned = True
                out |= self.names(node.value)
            if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Store) and \
                    isinstance(node.value, ast.Name) and node.value.id == name:
                out |= self._key(node.slice)
        if not assigned:
            self.unresolved.append(name)
        return out

    def _key(self, node: ast.AST) -> set[str]:
        """A key: a literal, or a name bound to an f-string whose values ``computed`` knows."""
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return {node.value}
        if isinstance(node, ast.JoinedStr) and isinstance(node.values[0], ast.Constant) and \
                node.values[0].value in self.computed:
            return {node.values[0].value + value for value in self.computed[node.values[0].value]}
        if isinstance(node, ast.Name):
            for a in ast.walk(self.scope):
                if isinstance(a, ast.Assign) and isinstance(a.value, ast.JoinedStr) and \
                        any(isinstance(t, ast.Name) and t.id == node.id for t in a.targets):
                    return self._key(a.value)
        self.unresolved.append(ast.unparse(node))
        return set()


class _HeartbeatCalls(ast.NodeVisitor):
    """Every ``Heartbeat(...)`` call of a module, with the innermost function around it."""

    def __init__(self) -> None:
        self.scopes: list[ast.AST] = []
        self.found: list[tuple[ast.AST, ast.Call]] = []

    def visit_FunctionDef(self, node: ast.AST) -> None:
        self.scopes.append(node)
        self.generic_visit(node)
        self.scopes.pop()

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_Call(self, node: ast.Call) -> None:
        # ``Heartbeat(session, run, role, instance, counters=...)`` or ``RoleLinks.beat(role, counters, info)``
        if ast.unparse(node.func).split(".")[-1] == "Heartbeat" or (
                isinstance(node.func, ast.Attribute) and node.func.attr == "beat"):
            self.found.append((self.scopes[-1], node))
        self.generic_visit(node)


def _heartbeat_sites() -> Iterator[tuple[Path, str, ast.AST, ast.Call]]:
    """Every ``Heartbeat(...)`` call in the role packages: (file, role, enclosing function, call)."""
    for package in ROLE_PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            calls = _HeartbeatCalls()
            calls.visit(ast.parse(path.read_text(encoding="utf-8")))
            for scope, call in calls.found:
                beat = ast.unparse(call.func).split(".")[-1] == "beat"
                if getattr(scope, "name", "") == "beat":
                    continue  # RoleLinks.beat forwards its caller's role: the caller is the site
                position = 0 if beat else 2
                role = call.args[position] if len(call.args) > position else next(
                    k.value for k in call.keywords if k.arg == "role")
                assert isinstance(role, ast.Constant), f"{path}: the Heartbeat's role is not a literal"
                yield path, role.value, scope, call


@pytest.fixture(scope="module")
def role_counters(tmp_path_factory) -> dict[str, dict[str, float]]:
    """role -> {counter name: a realistic value} for every counter name the code reports."""
    from actors.control import UNREACHABLE_REASONS

    tmp = tmp_path_factory.mktemp("roles")
    session = open_session(FabricConfig(listen=[f"tcp/127.0.0.1:{get_free_port()}"], shared_memory=False), "router")
    try:
        real = {"replay": _replay_counters(session, tmp), "learner": _learner_counters(tmp)}
        shared = _part_builders(session)
        out: dict[str, dict[str, float]] = {}
        unresolved: list[str] = []
        for path, role, scope, call in _heartbeat_sites():
            counters = next((k.value for k in call.keywords if k.arg == "counters"), None)
            if counters is None and ast.unparse(call.func).endswith(".beat") and len(call.args) > 1:
                counters = call.args[1]
            if counters is None:
                names: dict[str, float] = {}
            elif role in real and isinstance(counters, ast.Attribute):  # learner.counters, self.counters
                names = real[role]
            else:
                reader = _ClosureReader(scope, shared, {"unreachable_": UNREACHABLE_REASONS})
                names = dict.fromkeys(reader.names(counters), 3.0)
                unresolved += [f"{path.relative_to(REPO)} ({role}): {u}" for u in reader.unresolved]
            out.setdefault(role, {}).update(names)
    finally:
        session.close()
    assert not unresolved, f"counter names this test cannot follow; teach it: {unresolved}"
    return out


def test_the_roles_report_what_the_test_expects(role_counters):
    """The readers found the real sets (a guard against a reader that silently finds nothing)."""
    assert {"actor", "eval", "demos", "learner", "replay", "dashboard", "router"} <= set(role_counters)
    assert {"episodes", "sent", "weights_rejected_unforeseen_reason", "unreachable_ik_failed",
            "success_rate"} <= set(role_counters["actor"])
    assert {"ingest_rejected_decode", "ingest_error_oserror", "zmq_rejected_unforeseen_reason",
            "checkpoint_max_pause_ms", "restore_seconds"} <= set(role_counters["replay"])
    assert {"loss/depth0", "q_chosen/depth1", "updates"} <= set(role_counters["learner"])
    assert {"eval_success", "weights_superseded"} <= set(role_counters["eval"])


def test_every_counter_the_roles_report_is_catalogued(role_counters):
    missing = sorted(f"{role}/{name}" for role, names in role_counters.items() for name in names
                     if lookup(role, name) is None)
    assert not missing, f"add these to dashboard/metrics_catalog.py: {missing}"


def test_the_catalogue_gives_one_name_one_meaning():
    seen: dict[str, Family] = {}
    for role, entries in EXACT.items():
        families = [e for e in entries.values() if isinstance(e, Family)] + [f for _, f in BY_LABEL.get(role, ())]
        assert len({f.name for f in families}) == len(families), f"{role}: two counters share a family"
        for f in families:
            assert seen.setdefault(f.name, f) == f, f"{f.name} means two things"
            assert f.name.startswith("c2farm_") and f.name not in BUILT_IN and f.help.strip()
            assert f.name.endswith("_total") == (f.kind == "counter"), f.name
            assert f.label not in ("run", "role", "instance", "name")
            assert not f.name.endswith(("_per_s", "_ms", "_s")), f"{f.name}: use base units, rates in PromQL"
        prefixes = [p for p, _ in BY_LABEL.get(role, ())]
        assert not [(a, b) for a in prefixes for b in prefixes if a != b and b.startswith(a)], f"{role}: overlapping"
    assert set(BY_LABEL) <= set(EXACT)
    # an exact name wins over a prefix: a rate next to its by-reason family stays out
    assert lookup("actor", "unreachable_rate") == (EXACT["actor"]["unreachable_rate"], "")
    assert isinstance(lookup("actor", "unreachable_rate")[0], Skip)
    assert lookup("actor", "unreachable_ik_failed")[1] == "ik_failed"


# -- the real app, scraped and linted ------------------------------------------------------
@pytest.fixture
def serve() -> Iterator[Callable[[RoleTable], httpx.Client]]:
    """Serves a RoleTable with the real FastAPI app on a real uvicorn thread; returns a client."""
    running: list[tuple[uvicorn.Server, threading.Thread, httpx.Client]] = []

    def start(table: RoleTable) -> httpx.Client:
        port = get_free_port()
        server = uvicorn.Server(uvicorn.Config(create_app(table), host="127.0.0.1", port=port, log_level="warning",
                                               lifespan="off"))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        wait_for(lambda: server.started or not thread.is_alive(), 30, "uvicorn to start")
        client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10)
        running.append((server, thread, client))
        return client

    yield start
    for server, thread, client in running:
        client.close()
        server.should_exit = True
        thread.join(timeout=10)


def _fed_table(role_counters: dict[str, dict[str, float]]) -> RoleTable:
    """Two actors, one of them gone, every other role once; a NaN loss, an uncatalogued counter
    named like a dashboard metric (once a second TYPE line promtool rejected)."""
    table = RoleTable("run-1", gone_after_s=60.0)
    instances = {"actor": ["actor-0", "actor-1"], "dashboard": ["dashboard"]}
    for role, counters in sorted(role_counters.items()):
        for instance in instances.get(role, [role]):
            values = dict(counters)
            if role == "learner":
                values["loss/depth0"] = math.nan
            if role == "replay":
                values["checkpoint_max_pause_ms"] = 250.0
            if instance == "actor-1":
                values["role_alive"] = 7.0
            table.on_token(role, instance, True)
            table.on_status(Status(role, instance, "run-1", 11, "host-a", 0.0, "running", values))
    table.on_token("actor", "actor-1", False)
    table.on_rejected("a malformed status")
    return table


def promtool_check(body: bytes) -> tuple[int, str]:
    promtool = shutil.which("promtool")
    if promtool is None:
        pytest.fail("promtool is missing: apt-get install prometheus (.ci/run installs it)")
    done = subprocess.run([promtool, "check", "metrics"], input=body, capture_output=True, timeout=120)
    return done.returncode, (done.stdout + done.stderr).decode()


def test_metrics_pass_promtool(role_counters, serve, caplog):
    client = serve(_fed_table(role_counters))
    with caplog.at_level(logging.WARNING, logger="dashboard.metrics"):
        first, second = client.get("/metrics"), client.get("/metrics")
    assert first.status_code == 200 and first.headers["content-type"].startswith("text/plain; version=0.0.4")
    code, report = promtool_check(first.content)
    assert (code, report) == (0, ""), report

    text = first.text
    assert "# TYPE c2farm_replay_ingest_rejected_total counter" in text
    assert ('c2farm_replay_ingest_rejected_total{instance="replay",reason="decode",role="replay",'
            'run="run-1"} 0.0') in text
    assert 'c2farm_actor_unreachable_episodes_by_reason_total{instance="actor-0",reason="ik_failed",' in text
    assert 'c2farm_learner_loss{depth="0",instance="learner",role="learner",run="run-1"} NaN' in text
    assert 'c2farm_replay_checkpoint_max_pause_seconds{instance="replay",role="replay",run="run-1"} 0.25' in text
    assert 'c2farm_outbox_sent_total{instance="demos",role="demos",run="run-1"} 3.0' in text  # one name, two roles
    assert 'c2farm_role_alive{instance="actor-1",role="actor",run="run-1"} 0.0' in text
    assert 'c2farm_rejected_status_messages_total{run="run-1"} 1.0' in text
    assert f'{UNDOCUMENTED}{{instance="actor-1",name="role_alive",role="actor",run="run-1"}} 7.0' in text
    assert "_per_s" not in text and "samples_per_insert{" not in text
    assert text.count("# TYPE c2farm_role_alive ") == 1
    # the uncatalogued counter is logged once, not once per scrape
    warned = [r for r in caplog.records if "role_alive" in r.getMessage()]
    assert len(warned) == 1 and second.status_code == 200


def test_promtool_would_have_caught_the_old_exposition():
    """The check is not vacuous: a count exported as an untitled gauge is reported."""
    code, report = promtool_check(b"# TYPE c2farm_episodes gauge\nc2farm_episodes 4\n")
    assert "no help text" in report


def test_prometheus_text_is_the_same_exposition():
    table = RoleTable("run-1")
    table.on_token("learner", "learner", True)
    table.on_status(Status("learner", "learner", "run-1", 1, "h", 0.0, "running", {"updates": 5, "updates_per_s": 2}))
    text = prometheus_text(table.snapshot())
    assert 'c2farm_learner_updates_total{instance="learner",role="learner",run="run-1"} 5.0' in text
    assert "updates_per_s" not in text
