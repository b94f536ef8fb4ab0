"""Primitive bodies (boxes, cylinders, spheres) built with createMultiBody, in any PyBullet client.

Tasks spawn the same objects in the physics client and in the planner's collision client, so every
helper takes the client id explicitly.
"""

from __future__ import annotations

from collections.abc import Sequence

from actors.sim.bullet import p

#: RLBench-style colour list (a subset of its 20 named colours), RGBA.
COLOURS: dict[str, tuple[float, float, float, float]] = {
    "red": (1.0, 0.0, 0.0, 1), "green": (0.0, 0.8, 0.0, 1), "blue": (0.0, 0.0, 1.0, 1),
    "yellow": (1.0, 1.0, 0.0, 1), "cyan": (0.0, 1.0, 1.0, 1), "magenta": (1.0, 0.0, 1.0, 1),
    "orange": (1.0, 0.5, 0.0, 1), "purple": (0.5, 0.0, 0.5, 1), "white": (1.0, 1.0, 1.0, 1),
    "black": (0.1, 0.1, 0.1, 1), "grey": (0.5, 0.5, 0.5, 1), "olive": (0.5, 0.5, 0.0, 1),
    "navy": (0.0, 0.0, 0.5, 1), "maroon": (0.5, 0.0, 0.0, 1), "teal": (0.0, 0.5, 0.5, 1),
    "silver": (0.75, 0.75, 0.75, 1), "azure": (0.0, 0.5, 1.0, 1), "violet": (0.5, 0.0, 1.0, 1),
    "rose": (1.0, 0.0, 0.5, 1), "lime": (0.5, 1.0, 0.0, 1),
}

Vec3 = Sequence[float]
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def target_and_distractors(rng, distractors: int) -> list[str]:
    """Colour names for RLBench's variation 0, the one C2F-ARM trains on: the target red, distractors other colours.

    The colour tells the target apart; a task that drew it at random would ask the policy to
    find the target by a cue it is never told (RLBench's other variations come with language).
    """
    others = [n for n in COLOURS if n != "red"]
    return ["red"] + list(rng.choice(others, distractors, replace=False))


def box(client: int, half: Vec3, pos: Vec3, orn: Sequence[float] = IDENTITY, rgba=(0.6, 0.6, 0.6, 1),
        mass: float = 0.0, collide: bool = True) -> int:
    """A box; mass 0 makes it static."""
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client) if collide else -1
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=rgba, physicsClientId=client)
    return p.createMultiBody(mass, col, vis, pos, orn, physicsClientId=client)


def cylinder(client: int, radius: float, height: float, pos: Vec3, orn: Sequence[float] = IDENTITY,
             rgba=(0.6, 0.6, 0.6, 1), mass: float = 0.0) -> int:
    """An upright cylinder (axis = body z)."""
    col = p.createCollisionShape(p.GEOM_CYLINDER, radius=radius, height=height, physicsClientId=client)
    vis = p.createVisualShape(p.GEOM_CYLINDER, radius=radius, length=height, rgbaColor=rgba,
                              physicsClientId=client)
    return p.createMultiBody(mass, col, vis, pos, orn, physicsClientId=client)


def sphere(client: int, radius: float, pos: Vec3, rgba=(1, 0, 0, 1), mass: float = 0.0,
           collide: bool = True) -> int:
    """A sphere; ``collide=False`` gives a visual-only marker (reach targets, lift zones)."""
    col = p.createCollisionShape(p.GEOM_SPHERE, radius=radius, physicsClientId=client) if collide else -1
    vis = p.createVisualShape(p.GEOM_SPHERE, radius=radius, rgbaColor=rgba, physicsClientId=client)
    return p.createMultiBody(mass, col, vis, pos, IDENTITY, physicsClientId=client)


def compound(client: int, parts: Sequence[tuple[str, Sequence[float], Vec3]], pos: Vec3,
             orn: Sequence[float] = IDENTITY, rgba=(0.6, 0.6, 0.6, 1), mass: float = 0.0) -> int:
    """One rigid body made of boxes/cylinders: parts = (kind, dims, offset) in the body frame.

    kind "box": dims = half extents; kind "cylinder": dims = (radius, height).
    """
    types, half, radii, lengths, offsets = [], [], [], [], []
    for kind, dims, off in parts:
        if kind == "box":
            types.append(p.GEOM_BOX)
            half.append(list(dims))
            radii.append(0.0)
            lengths.append(0.0)
        else:
            types.append(p.GEOM_CYLINDER)
            half.append([0, 0, 0])
            radii.append(dims[0])
            lengths.append(dims[1])
        offsets.append(list(off))
    col = p.createCollisionShapeArray(types, radii=radii, halfExtents=half, lengths=lengths,
                                      collisionFramePositions=offsets, physicsClientId=client)
    vis = p.createVisualShapeArray(types, radii=radii, halfExtents=half, lengths=lengths,
                                   visualFramePositions=offsets, rgbaColors=[rgba] * len(types),
                                   physicsClientId=client)
    return p.createMultiBody(mass, col, vis, pos, orn, physicsClientId=client)
