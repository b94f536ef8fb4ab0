"""The import graph keeps the architecture: roles meet only in protocol/, and no role loads what it does not use.

Roles (actors, learner, replay server, dashboard) are thin shells joined by ``protocol/``; only
``deploy/`` composes them. A role that imported another would pull its dependencies (PyBullet,
torch, franky) into processes that never use them and couple two things meant to change apart.
Every import counts, including those inside functions.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest
from conftest import REPO

ROLES = ("actors", "learner", "replay_server", "dashboard")
#: Shared layers: what roles may import. They import no role and not the composer (deploy).
SHARED = ("protocol", "qattention")


def imports(path: Path) -> set[str]:
    """Every absolute module a file imports, at any depth (lazy imports in functions too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


def package_files(package: str) -> list[Path]:
    return sorted((REPO / package).rglob("*.py"))


def folder(path: Path) -> str:
    """The module's folder as a dotted name: actors/sim/scene.py -> actors.sim."""
    return ".".join(path.relative_to(REPO).parent.parts)


@pytest.mark.parametrize("package", ROLES + SHARED)
def test_a_role_imports_no_other_role_and_shared_layers_import_no_role(package: str):
    forbidden = {p for p in ROLES + ("deploy",) if p != package} if package in ROLES else set(ROLES + ("deploy",))
    offenders = [f"{path.relative_to(REPO)} imports {module}"
                 for path in package_files(package) for module in sorted(imports(path))
                 if module.split(".")[0] in forbidden]
    assert not offenders, "\n".join(offenders)


def test_the_harness_drives_the_system_from_outside():
    """harness/ (the multi-host bench) starts roles through the CLI like a second machine would; it imports
    no project package, so it cannot lean on anything a real machine would not have."""
    project = set(ROLES + SHARED + ("deploy",))
    offenders = [f"{path.relative_to(REPO)} imports {module}"
                 for path in package_files("harness") for module in sorted(imports(path))
                 if module.split(".")[0] in project]
    assert package_files("harness") and not offenders, "\n".join(offenders)


def test_no_two_folders_import_each_other():
    """Folder cycles (a -> b -> a, at any length) hide behind lazy imports; there are none."""
    graph: dict[str, set[str]] = defaultdict(set)
    folders = {folder(p) for package in ROLES + SHARED for p in package_files(package)}
    for package in ROLES + SHARED:
        for path in package_files(package):
            here = folder(path)
            for module in imports(path):
                parts = module.split(".")
                target = next((".".join(parts[:n]) for n in range(len(parts), 0, -1) if ".".join(parts[:n]) in folders),
                              None)
                if (
                    target
                    and target != here
                    and not here.startswith(target + ".")
                    and not target.startswith(here + ".")
                ):
                    graph[here].add(target)
    cycles = []

    def visit(node: str, trail: list[str]) -> None:
        for nxt in sorted(graph[node]):
            if nxt in trail:
                cycles.append(" -> ".join(trail[trail.index(nxt):] + [nxt]))
            elif len(trail) < len(folders):
                visit(nxt, trail + [nxt])

    for start in sorted(graph):
        visit(start, [start])
    assert not cycles, "\n".join(sorted(set(cycles)))


#: role -> what its process imports to start (deploy.roles' entry and the config it reads)
ROLE_IMPORTS = {
    "learner": "import learner.train",
    "replay": "import replay_server.service",
    "dashboard": "import dashboard.service",
}


@pytest.mark.parametrize("role", sorted(ROLE_IMPORTS))
def test_the_learner_replay_and_dashboard_never_load_the_simulator(role: str):
    """Their processes import their entry point and derive the network config; PyBullet stays out."""
    code = (f"import sys; {ROLE_IMPORTS[role]}; from deploy.config import RunConfig; from deploy import roles; "
            "roles.network_config(RunConfig()); roles.demo_dir(RunConfig()); "
            "loaded = sorted(m for m in ('pybullet', 'ompl', 'ruckig', 'franky', 'mujoco') if m in sys.modules); "
            "print(','.join(loaded))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"the {role} loads {out.stdout.strip()}"


def test_the_dashboard_the_replay_and_the_demo_source_do_not_load_torch():
    code = ("import sys; import dashboard.service, replay_server.service, actors.demo_source; "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
