"""The record of one collider as every family reads it (no Taichi): simcli.colliders builds it from the
scene's colliders, simcli.rigid from its free rigid bodies (moving, named, ``rigid``), so that both share
one definition and a field added for one (restitution, a Mesh's grid) is there for the other."""

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ColliderSpec:
    """One obstacle. ``kind``/``contact``/``axis`` are compile-time; the rest is run-time data."""

    kind: str  # Plane | Box | Sphere | Cylinder
    contact: str  # slip | sticky | separate
    axis: int  # cylinder axis (0, 1, 2); 0 for the others
    a: tuple  # Plane: point, Box: lower, Sphere/Cylinder: center
    b: tuple  # Plane: unit normal, Box: upper, others: zeros
    radius: float  # Sphere/Cylinder radius [m]
    half_height: float  # Cylinder half length [m]
    friction: float  # Coulomb coefficient [-]
    moving: bool = False  # compile-time: a prescribed motion (simcli.motion) transforms the query point
    name: str | None = None  # named colliders report forces
    centre: tuple = ()  # default pivot (simcli.motion.collider_centre)
    restitution: float = 0.0  # compile-time: > 0 compiles the restitution paths (0: the code of before)
    mesh: Any = None  # Mesh: simcli.collider_mesh.MeshSDF (body frame = the pose at t = 0)
    rigid: bool = False  # a free rigid body (simcli.rigid): families may count its loads more completely
