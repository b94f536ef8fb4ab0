"""PandaEnv: the simulated world an actor acts in (an ``actors.environment.Env``), a PyBullet Panda and a task.

One step = one C2F-ARM decision: the control agent (IK, OMPL, Ruckig) moves the grasp frame to
the pose and then sets the gripper (RLBench's MoveArmThenGripper). Reward is sparse: 100 when the
task succeeds (which ends the episode), else 0; an unreachable pose ends the episode with
``unreachable_reward``. It lives beside ``actors.sim`` (the world) and ``actors.control`` (the
arm's motion) because it joins the two.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from actors.control.agent import ControlAgent, ControlConfig
from actors.environment import SUCCESS_REWARD, StepResult
from actors.sim import cameras as cams
from actors.sim.config import SimConfig
from actors.sim.scene import HAND_LINK, PandaScene
from actors.sim.tasks import make_task
from protocol.observation import Observation, camera_frame

#: Called with every control step's Observation while a step executes (demo recording).
StepRecorder = Callable[[Observation], None]


class PandaEnv:
    """A seeded, deterministic Panda world for one task."""

    def __init__(self, config: SimConfig | None = None) -> None:
        self.config = config or SimConfig()
        self.task = make_task(self.config.task)
        self.episode_length = self.config.episode_length or self.task.episode_length
        self.scene = PandaScene(self.config.physics_hz)
        c = self.config
        self.control = ControlAgent(self.scene, ControlConfig(
            planner=c.planner, planning_time=c.planning_time, simplify_time=c.simplify_time,
            velocity_scale=c.velocity_scale, acceleration_scale=c.acceleration_scale, control_hz=c.control_hz),
            seed=c.seed)
        self._k = cams.intrinsics(c.image_size, c.fov_deg)
        self._wrist_k = cams.intrinsics(c.image_size, cams.WRIST_FOV_DEG)
        self._fixed = {n: cams.fixed_extrinsics(cams.FIXED_CAMERAS[n]) for n in cams.FIXED_CAMERAS}
        self.steps = 0
        self.success = False
        self.seed: int | None = None

    @property
    def task_name(self) -> str:
        return self.config.task

    @property
    def scene_bounds(self) -> tuple[float, ...]:
        """The task's depth-0 voxel cube: xmin, ymin, zmin, xmax, ymax, zmax (metres, world)."""
        return tuple(self.task.scene_bounds)

    def reset(self, seed: int | None = None) -> Observation:
        """New episode: robot home, task objects re-sampled from ``seed`` (default: config.seed)."""
        self.seed = self.config.seed if seed is None else int(seed)
        rng = np.random.default_rng(self.seed)
        self.scene.reset_robot()
        self.task.build(self.scene, rng)
        self.control.set_obstacles(self.task.spawn, self.task.bodies, self.task.obstacles, self.task.planner_ignores())
        self.steps, self.success = 0, False
        return self.observe()

    def step(self, action: np.ndarray, record: StepRecorder | None = None, linear: bool = False) -> StepResult:
        """Execute one next-best pose [x, y, z, qx, qy, qz, qw, gripper_open]; ``record`` sees every control step.

        ``linear`` (scripted demos only) asks for a straight Cartesian motion of the grasp frame.
        """
        if self.seed is None:
            raise RuntimeError("call reset() before step()")

        last: list[Observation] = []

        def on_step() -> None:
            self.success = self.success or self.task.success()  # latched: a press or a drop counts when it happens
            if record is not None:
                last[:] = [self.observe()]
                record(last[0])

        outcome = self.control.execute(action, self.task.scene_bounds, on_step, linear=linear)
        self.steps += 1
        info = {"timings": outcome.timings, "control_steps": outcome.control_steps, "used_ompl": outcome.used_ompl}
        obs = last[0] if last else self.observe()  # the last recorded control step *is* the observation after it
        obs.step = self.steps
        if outcome.unreachable:
            info["reason"] = outcome.reason
            return StepResult(obs, self.config.unreachable_reward, True, False, True, info)
        timeout = self.steps >= self.episode_length
        info["timeout"] = timeout and not self.success
        reward = SUCCESS_REWARD if self.success else 0.0
        return StepResult(obs, reward, self.success or timeout, self.success, False, info)

    def reachable(self, action: np.ndarray) -> bool:
        """Could the arm take this next-best pose from where it is now? (IK only; see ControlAgent.reachable)."""
        return self.control.reachable(action, self.task.scene_bounds)

    def observe(self) -> Observation:
        """Render the configured cameras and read the proprioception."""
        s, c = self.scene, self.config
        frames = {}
        for name in c.cameras:
            if name == "wrist":
                k, e = self._wrist_k, cams.wrist_extrinsics(*s.link_pose(HAND_LINK))
                fov = cams.WRIST_FOV_DEG
            else:
                k, e, fov = self._k, self._fixed[name], c.fov_deg
            rgb, depth = cams.render(s.client, e, c.image_size, fov)
            frames[name] = camera_frame(rgb, depth, k, e)
        q, qd = s.joint_state()
        return Observation(
            cameras=frames, gripper_pose=s.grasp_pose().astype(np.float32), gripper_open=float(s.gripper_open),
            finger_positions=s.finger_positions().astype(np.float32), joint_positions=q.astype(np.float32),
            joint_velocities=qd.astype(np.float32), step=self.steps)

    def demo_waypoints(self):
        """The task's scripted waypoints for this episode (call right after reset)."""
        return self.task.waypoints()

    def close(self) -> None:
        self.control.close()
        self.scene.close()
