"""Control agent: IK (ik.py), OMPL planning in a collision client (planner.py, collision.py), Ruckig
time parameterisation (trajectory.py) and execution in the physics (agent.py)."""

from actors.control.agent import UNREACHABLE_REASONS, ControlAgent, ControlConfig, ControlOutcome

__all__ = ["UNREACHABLE_REASONS", "ControlAgent", "ControlConfig", "ControlOutcome"]
