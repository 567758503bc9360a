"""The scene's ``rigid_bodies:`` entries (pydantic, no Taichi)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from simcli.scene.morphs import BoxShape, CylinderShape, MeshShape, SphereShape

DOFS = ("x", "y", "z", "rx", "ry", "rz")

RigidShape = Annotated[BoxShape | SphereShape | CylinderShape | MeshShape, Field(discriminator="type")]


class RigidBody(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)

    name: str = Field(
        min_length=1,
        description="Unique name (among rigid bodies, colliders and entities): "
        "sim.h5 /rigid_bodies/<name>/..., vtk/<name>.pvd.",
    )
    morph: RigidShape = Field(
        description="Shape at t = 0: Box (axis-aligned), Sphere (a disk in 2D), Cylinder (3D) or Mesh (3D: a "
        "closed triangle surface, scaled, rotated and translated as a Mesh morph; not with SF; 2D: a closed "
        "polygon in the x-y plane, one OBJ f line or l lines closing a loop, rotate the angle about z, with "
        "MPM and SPH entities). Mass, centre of mass and inertia follow from it and rho (a Mesh: exact "
        "polyhedral or polygon integrals)."
    )
    rho: float = Field(gt=0, description="Density [kg/m^3] (2D: per metre of depth).")
    sdf_cell: float | None = Field(
        None,
        gt=0,
        description="Mesh bodies: cell [m] of the signed-distance grid the materials meet (default, as for "
        "Mesh colliders: half the finest of the MPM grid cell, the PBD and SPH particle_size and the FEM "
        "element size).",
    )
    velocity: list[float] | None = Field(None, description="Initial velocity of the centre of mass [m/s].")
    angular_velocity: list[float] | None = Field(
        None, description="Initial angular velocity [rad/s] (3 components in 3D, 1 about z in 2D)."
    )
    friction: float = Field(
        0.0,
        ge=0,
        description="Coulomb coefficient [-] of its surface against the materials (as a collider's "
        "friction), the domain walls and other rigid bodies (the geometric mean of the two).",
    )
    restitution: float = Field(
        0.0, ge=0, le=1, description="Normal restitution [-] against walls and other rigid bodies."
    )
    boundary: Literal["slip", "sticky", "separate"] = Field(
        "separate", description="Contact condition the materials meet on its surface (as for colliders)."
    )
    cpic: bool = Field(
        False,
        description="MPM, Box bodies: Compatible Particle-In-Cell (Hu et al. 2018), as a Box collider's "
        "cpic: a particle and a grid node on opposite sides of the body (a plate along its thinnest axis) "
        "exchange nothing, so a free plate thinner than the kernel's support cuts the material cleanly; the "
        "impulse of that exchange is the body's load (docs/RIGID.md, CPIC bodies). Default off.",
    )
    fixed_dofs: list[Literal["x", "y", "z", "rx", "ry", "rz"]] = Field(
        default_factory=list,
        description="Degrees of freedom held at their initial velocity (e.g. [x, y, z, rx, ry] for a wheel "
        "turning about z on a fixed axle). 2D: x, y, rz.",
    )
