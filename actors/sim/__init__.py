"""The simulated world: PyBullet Panda scene, RLBench-style cameras and the task ladder.

``PandaEnv`` (``actors.panda_env``) joins this world to the control agent. Names resolve lazily,
so ``from actors.sim import SimConfig`` (the launcher's config) does not load pybullet.
"""

from importlib import import_module

_EXPORTS = {"SimConfig": "actors.sim.config", "TASKS": "actors.sim.task_specs",
            "UnknownTaskError": "actors.sim.task_specs", "make_task": "actors.sim.tasks"}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'actors.sim' has no attribute {name!r}")
