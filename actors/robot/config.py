"""Typed settings of a robot actor: the arm, its safety limits and its cameras."""

from __future__ import annotations

from dataclasses import dataclass, field

from protocol.config_checks import above, at_least, finite, non_empty, one_of
from protocol.observation import CAMERA_NAMES


@dataclass
class SafetyConfig:
    """Where the arm may be sent; a pose outside is refused and counted, never sent to the arm."""

    #: lower corner of the allowed grasp-frame box, metres, robot base frame
    workspace_min: tuple[float, float, float] = (0.2, -0.4, 0.0)
    #: upper corner of the allowed grasp-frame box, metres, robot base frame
    workspace_max: tuple[float, float, float] = (0.75, 0.4, 0.6)
    table_height: float = 0.0  #: z of the table top, metres, robot base frame
    table_clearance: float = 0.01  #: the grasp frame stays at least this far above the table top, metres
    max_step: float = 0.5  #: longest straight-line move of the grasp frame in one decision, metres
    #: largest angle between the gripper's approach axis and straight down, degrees (90 allows a horizontal approach)
    max_tilt_deg: float = 60.0
    #: largest turn of the gripper about the vertical from the top-down frame with fingers along y, degrees (the wrist's
    #: range)
    max_yaw_deg: float = 120.0

    def __post_init__(self) -> None:
        self.workspace_min, self.workspace_max = tuple(self.workspace_min), tuple(self.workspace_max)
        if len(self.workspace_min) != 3 or len(self.workspace_max) != 3:
            raise ValueError("workspace_min and workspace_max need three values (x, y, z)")
        finite(self, "workspace_min", "workspace_max", "table_height", "table_clearance", "max_step")
        if any(lo >= hi for lo, hi in zip(self.workspace_min, self.workspace_max)):
            raise ValueError("workspace_min must be below workspace_max on every axis")
        if self.max_step <= 0 or self.table_clearance < 0:
            raise ValueError("max_step must be > 0 and table_clearance >= 0")
        if not (0 < self.max_tilt_deg <= 180 and 0 < self.max_yaw_deg <= 180):
            raise ValueError("max_tilt_deg and max_yaw_deg must be in (0, 180]")


@dataclass
class FrankaConfig:
    """How the Franka is driven through franky."""

    host: str = "172.16.0.2"  #: the robot's FCI address (franky-sim: the loopback address it prints); not empty
    #: fraction of the Panda's velocity, acceleration and jerk limits (franky relative_dynamics_factor), in (0, 1]
    dynamics_factor: float = 0.1
    #: collision torque threshold, Nm, > 0 (a contact above it stops the arm with a reflex)
    torque_threshold: float = 20.0
    force_threshold: float = 30.0  #: collision force threshold, N, > 0
    #: a move counts as reached when the grasp frame ends this close to the target, metres, > 0
    reach_tolerance: float = 0.01
    #: a move still running after this long (seconds, > 0) is stopped and counted as failed
    move_timeout_s: float = 30.0
    #: after a motion ends, wait at most this long (seconds, >= 0) for the arm to stand still before judging it
    settle_timeout_s: float = 3.0
    gripper_speed: float = 0.05  #: finger speed, m/s, > 0
    gripper_force: float = 20.0  #: grasping force, N, > 0
    #: the arm counts as standing still once every joint moves slower than this, rad/s, > 0 (stop timing)
    still_speed: float = 0.01
    #: joint positions (rad) the arm unwinds to, in joint space, when a Cartesian move home fails (Franka's "ready"
    #: posture)
    home_joints: tuple[float, ...] = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)
    #: relative dynamics of a move's first try and of each retry, each in (0, 1]: when franky's trajectory generator
    #: (Ruckig) refuses a motion on a numerical edge ("Motion planner failed", errors -101/-110/-111), the arm's error
    #: is cleared and the move is planned again, slower; one number = no retry
    replan_dynamics: tuple[float, ...] = (1.0, 0.7, 0.5)

    def __post_init__(self) -> None:
        if not 0 < self.dynamics_factor <= 1:
            raise ValueError("dynamics_factor must be in (0, 1]")
        if self.reach_tolerance <= 0 or self.move_timeout_s <= 0 or self.still_speed <= 0:
            raise ValueError("reach_tolerance, move_timeout_s and still_speed must be > 0")
        self.home_joints = tuple(float(q) for q in self.home_joints)
        if len(self.home_joints) != 7:
            raise ValueError("home_joints needs the 7 joint positions of the arm, radians")
        self.replan_dynamics = tuple(float(f) for f in self.replan_dynamics)
        if not self.replan_dynamics or not all(0 < f <= 1 for f in self.replan_dynamics):
            raise ValueError(f"replan_dynamics needs one or more factors in (0, 1] (got {self.replan_dynamics})")
        non_empty(self, "host")
        above(self, 0, "torque_threshold", "force_threshold", "gripper_speed", "gripper_force")
        at_least(self, 0, "settle_timeout_s")
        finite(self, "reach_tolerance", "move_timeout_s", "still_speed", "home_joints")


@dataclass
class CameraConfig:
    """One RGB-D camera of the rig."""

    name: str = "front"  #: the Observation's camera name, one of protocol.observation.CAMERA_NAMES
    kind: str = "realsense"  #: realsense, or mujoco (a render of franky-sim's scene; tests and benchmarks)
    serial: str = ""  #: RealSense serial number; empty = the only one connected
    image_size: int = 128  #: square side the frame is resized/cropped to, pixels (C2F-ARM uses 128)
    #: YAML with the camera-to-robot-base pose (see actors/robot/cameras.py); empty = the built-in pose of a mujoco
    #: camera
    extrinsics_file: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ("realsense", "mujoco"):
            raise ValueError(f"camera kind {self.kind!r}: choose realsense or mujoco")
        if self.image_size < 8:
            raise ValueError("image_size must be >= 8")
        one_of(self, "name", CAMERA_NAMES)


@dataclass
class RobotConfig:
    """A robot actor's arm, safety limits, cameras and episodes."""

    #: franka (a real arm through franky), or franky-sim (franky-sim started inside the actor, on loopback)
    arm: str = "franka"
    #: grasp-frame pose (xyz + quaternion xyzw) the arm returns to before each episode
    home: tuple[float, ...] = (0.45, 0.0, 0.4, 1.0, 0.0, 0.0, 0.0)
    wait_for_reset: bool = True  #: wait for the operator's "reset done" before each episode
    #: after the last decision, wait this long (seconds, > 0) for the operator's success / fail; then a timeout (reward
    #: 0)
    verdict_wait_s: float = 30.0
    #: franky-sim only: a scripted success check (grasp frame within 2 cm of the target) stands in for the person
    scripted_operator: bool = False
    #: depth-0 voxel box the policy picks poses in (xmin ymin zmin xmax ymax zmax), metres, robot base frame, sent with
    #: every observation; empty = the safety workspace box, z from the table top
    scene_bounds: tuple[float, ...] = ()
    #: also play the evaluator's greedy episodes here (actor.eval_episodes on seeds actor.eval_seed..., every
    #: actor.eval_every_versions weights versions) into runs/<id>/metrics/eval.csv; for a run with no simulated
    #: evaluator
    evaluate: bool = False
    #: with evaluate: at most this share of the arm's time goes to greedy evaluations (after one that took T s, training
    #: episodes get T * (1 - share) / share s before the next); the one arm does both, so a fast learner must not keep
    #: it evaluating
    eval_share: float = 0.5
    franka: FrankaConfig = field(default_factory=FrankaConfig)  #: the Franka through franky
    safety: SafetyConfig = field(default_factory=SafetyConfig)  #: workspace box, table, step limit
    #: the RGB-D cameras, at least one, one per Observation camera (names distinct)
    cameras: list[CameraConfig] = field(default_factory=lambda: [CameraConfig()])

    def __post_init__(self) -> None:
        if self.arm not in ("franka", "franky-sim"):
            raise ValueError(f"robot arm {self.arm!r}: choose franka or franky-sim")
        self.home = tuple(float(v) for v in self.home)
        if len(self.home) != 7:
            raise ValueError("home needs 7 numbers: xyz + quaternion xyzw")
        if not 0.0 < self.eval_share <= 1.0:
            raise ValueError("eval_share must be in (0, 1]")
        finite(self, "home")
        if sum(q * q for q in self.home[3:]) < 1e-6:
            raise ValueError(f"home quaternion (its last 4 numbers, xyzw) must not be zero (got {self.home[3:]})")
        above(self, 0, "verdict_wait_s")
        if not self.cameras:
            raise ValueError("cameras must name at least one camera (got [])")
        names = [c.name for c in self.cameras]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"cameras must have distinct names (got {', '.join(repeated)} twice)")
        if self.scripted_operator and self.arm != "franky-sim":
            raise ValueError("scripted_operator needs arm: franky-sim (it reads the simulated target)")
        self.scene_bounds = tuple(float(v) for v in self.scene_bounds)
        if len(self.scene_bounds) not in (0, 6):
            raise ValueError("scene_bounds needs 6 numbers (min xyz, max xyz), or none for the safety workspace")
        bounds = self.depth0_bounds
        if not all(-1e3 < lo < hi < 1e3 for lo, hi in zip(bounds[:3], bounds[3:])):
            raise ValueError(
                f"scene bounds {bounds} must be finite with min < max on every axis (is the table top below "
                "safety.workspace_max?)"
            )

    @property
    def depth0_bounds(self) -> tuple[float, ...]:
        """The policy's depth-0 box: ``scene_bounds``, else the safety workspace from the table top up.

        Voxels outside the box the safety limits allow are poses the arm would refuse: an
        untrained policy choosing among them would end nearly every episode unreachable.
        """
        if self.scene_bounds:
            return self.scene_bounds
        (x0, y0, _), (x1, y1, z1) = self.safety.workspace_min, self.safety.workspace_max
        return (x0, y0, self.safety.table_height, x1, y1, z1)
