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
