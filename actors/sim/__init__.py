"""The actors' world: PyBullet Panda scene, RLBench-style cameras, the task ladder and PandaEnv.

Names are resolved lazily so that ``actors.control`` can import ``actors.sim.scene`` without a cycle.
"""

from importlib import import_module

_EXPORTS = {
    "SimConfig": "actors.sim.config", "PandaEnv": "actors.sim.env", "StepResult": "actors.sim.env",
    "SUCCESS_REWARD": "actors.sim.env", "TASKS": "actors.sim.tasks", "UnknownTaskError": "actors.sim.tasks",
    "make_task": "actors.sim.tasks",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'actors.sim' has no attribute {name!r}")
