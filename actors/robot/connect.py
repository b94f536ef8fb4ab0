"""Opening the configured arm with its cameras: a Franka through franky, or franky-sim started in this process."""

from __future__ import annotations

import contextlib
import dataclasses

from actors.robot.config import RobotConfig
from actors.robot.franka import FrankaArm


def make_cameras(robot: RobotConfig, sim, stack: contextlib.ExitStack) -> list:
    """The configured cameras: RealSense devices, or renders of the franky-sim scene."""
    cameras = []
    for cam in robot.cameras:
        if cam.kind == "mujoco":
            if sim is None:
                raise ValueError(f"camera {cam.name}: kind mujoco needs robot.arm franky-sim")
            cameras.append(sim.camera(cam.name, cam.image_size))
        else:
            from actors.robot.cameras import load_extrinsics
            from actors.robot.realsense import RealSenseCamera

            if not cam.extrinsics_file:
                raise ValueError(f"camera {cam.name}: a RealSense camera needs extrinsics_file (camera-to-base YAML)")
            camera = RealSenseCamera(cam.name, load_extrinsics(cam.extrinsics_file), cam.serial, cam.image_size)
            stack.callback(camera.close)
            cameras.append(camera)
    return cameras


def open_arm(robot: RobotConfig, stack: contextlib.ExitStack):
    """(connected arm, franky-sim or None): the configured arm with its cameras, closed by ``stack``.

    ``robot.arm: franky-sim`` starts franky-sim in this process first (loopback, MuJoCo cameras).
    """
    sim = None
    if robot.arm == "franky-sim":
        from actors.robot.franky_sim import FrankySim, SimSceneConfig

        sim = stack.enter_context(FrankySim(SimSceneConfig(cameras=tuple(c.name for c in robot.cameras))))
    host = sim.hostname if sim is not None else robot.franka.host
    arm = FrankaArm(dataclasses.replace(robot.franka, host=host), robot.safety, make_cameras(robot, sim, stack))
    arm.connect()
    stack.callback(arm.disconnect)
    return arm, sim


def open_env(robot: RobotConfig, task: str, episode_length: int, stop, stack: contextlib.ExitStack,
             terminal=None):
    """(arm, operator channel, RobotEnv): the configured arm, the channel the operator speaks on and the
    environment the actor loop steps, closed by ``stack``.

    The operator's keys come from ``terminal`` when given (its settings restored on the way out); on
    franky-sim with ``robot.scripted_operator`` the scripted reach check sets scenes and judges.
    """
    from actors.robot.env import RobotEnv
    from actors.robot.operator import OperatorChannel, TerminalOperator
    from actors.robot.reach_operator import ReachOperator

    arm, sim = open_arm(robot, stack)
    channel = OperatorChannel(on_stop=arm.stop, on_resume=arm.resume)
    if terminal is not None:
        operator = stack.enter_context(TerminalOperator(terminal, channel))
        print(operator.help, flush=True)
    scripted = ReachOperator(sim, channel) if robot.scripted_operator else None
    return arm, channel, RobotEnv(arm, channel, robot, task, episode_length, stop, scripted)
