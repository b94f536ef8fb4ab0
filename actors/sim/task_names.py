"""The task ladder's names, easiest first, without loading the physics engine.

Command-line help and pre-flight checks need the names before anything simulates; the
registry in ``actors.sim.tasks`` (which imports pybullet) checks it holds exactly these.
"""

TASKS: tuple[str, ...] = ("reach_target", "push_button", "pick_and_lift", "lift_lid", "open_drawer", "put_in_bin",
                          "stack_wine", "put_item_in_drawer")
#: The task ``sim.task`` names unless a preset or the command line says otherwise.
DEFAULT_TASK = "reach_target"
