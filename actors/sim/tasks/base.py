"""What a task is: its objects, their seeded randomisation, its success test and its scripted waypoints.

A task samples its parameters once per episode (``sample``), then ``spawn`` builds the same objects
in any client: the physics client, and the planner's collision client (only ``obstacles`` matter there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from actors.sim.bullet import p
from actors.sim.scene import PandaScene
from actors.sim.task_specs import TaskSpec, task_spec

TOP_DOWN = p.getQuaternionFromEuler((np.pi, 0.0, 0.0))


def top_down(yaw: float) -> np.ndarray:
    """Grasp-frame quaternion pointing the fingers at the table, rotated by ``yaw`` about world z."""
    return np.array(p.getQuaternionFromEuler((np.pi, 0.0, yaw)))


def horizontal(yaw: float) -> np.ndarray:
    """Grasp-frame quaternion pointing the fingers horizontally along (cos yaw, sin yaw, 0), closing sideways."""
    q_yaw = p.getQuaternionFromEuler((0.0, 0.0, yaw))
    q_pitch = p.getQuaternionFromEuler((0.0, np.pi / 2, 0.0))
    return np.array(p.multiplyTransforms((0, 0, 0), q_yaw, (0, 0, 0), q_pitch)[1])


@dataclass(frozen=True)
class Waypoint:
    """One scripted next-best pose: grasp-frame xyz + quat xyzw, and the gripper state after reaching it."""

    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    gripper_open: float
    linear: bool = False  #: move along a straight Cartesian line (RLBench's "linear" extension)

    def action(self) -> np.ndarray:
        return np.array([*self.position, *self.quaternion, self.gripper_open], dtype=np.float32)


def waypoint(pos, quat, gripper_open: float, linear: bool = False) -> Waypoint:
    return Waypoint(tuple(float(v) for v in pos), tuple(float(v) for v in quat), float(gripper_open), linear)


def yaw_rotate(yaw: float, v) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])


def sample_positions(rng: np.random.Generator, n: int, low, high, min_dist: float, tries: int = 1000) -> list:
    """``n`` points uniformly in the box [low, high], pairwise at least ``min_dist`` apart in xy (RLBench spawn)."""
    pts: list[np.ndarray] = []
    for _ in range(tries):
        c = rng.uniform(low, high)
        if all(np.linalg.norm(c[:2] - q[:2]) >= min_dist for q in pts):
            pts.append(c)
            if len(pts) == n:
                return pts
    raise RuntimeError("could not place objects")


class Task:
    """Base class; subclasses set the class attributes and implement the four hooks."""

    name: str = ""
    #: names of spawned bodies the motion planner must avoid
    obstacles: tuple[str, ...] = ()

    @property
    def spec(self) -> TaskSpec:
        """Episode length, revision and depth-0 box: ``actors.sim.task_specs``, read without pybullet too."""
        return task_spec(self.name)

    @property
    def episode_length(self) -> int:
        return self.spec.episode_length

    @property
    def scene_bounds(self) -> tuple[float, ...]:
        return self.spec.scene_bounds

    @property
    def revision(self) -> int:
        return self.spec.revision

    def planner_ignores(self) -> list[tuple[str, int]]:
        """(obstacle name, link) parts the planner may touch, e.g. handles the fingers close on."""
        return []

    def __init__(self) -> None:
        self.bodies: dict[str, int] = {}
        self.scene: PandaScene | None = None

    # hooks -------------------------------------------------------------------------------------
    def sample(self, rng: np.random.Generator) -> None:
        """Draw this episode's parameters (positions, yaws, colours, variation)."""
        raise NotImplementedError

    def spawn(self, client: int) -> dict[str, int]:
        """Create the objects in ``client`` from the sampled parameters; name -> body id."""
        raise NotImplementedError

    def waypoints(self) -> list[Waypoint]:
        """The scripted demo: next-best poses in order."""
        raise NotImplementedError

    def success(self) -> bool:
        """Whether the task is solved in the physics client now."""
        raise NotImplementedError

    # shared ------------------------------------------------------------------------------------
    def graspables(self) -> list[tuple[int, int]]:
        """(body, link) pairs the fake grasp may attach; default none."""
        return []

    def build(self, scene: PandaScene, rng: np.random.Generator) -> None:
        """Sample, spawn in the physics client and let the objects settle."""
        self.remove()
        self.scene = scene
        self.sample(rng)
        self.bodies = self.spawn(scene.client)
        scene.graspables = self.graspables()
        scene.step(int(0.1 * scene.physics_hz))

    def remove(self) -> None:
        if self.scene is not None:
            for body in self.bodies.values():
                p.removeBody(body, physicsClientId=self.scene.client)
        self.bodies = {}

    # helpers for subclasses --------------------------------------------------------------------
    def pose_of(self, name: str, link: int = -1) -> tuple[np.ndarray, np.ndarray]:
        cid = self.scene.client
        if link == -1:
            pos, orn = p.getBasePositionAndOrientation(self.bodies[name], physicsClientId=cid)
        else:
            pos, orn = p.getLinkState(self.bodies[name], link, physicsClientId=cid)[4:6]
        return np.array(pos), np.array(orn)

    def joint_position(self, name: str, joint: int) -> float:
        return p.getJointState(self.bodies[name], joint, physicsClientId=self.scene.client)[0]

    def nothing_grasped(self) -> bool:
        return self.scene.grasped is None
