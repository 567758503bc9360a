"""The FEM.Cloth material (pydantic, no Taichi)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from simcli.scene.material_base import _Solid
from simcli.scene.morphs import Region

MORPHS = ("Rectangle", "Mesh")


class ClothTraction(BaseModel):
    """A dead-load traction on the sheet's free edges inside a region (FEM solids' boundary_conditions
    traction, on a shell's edge faces: area = edge length x thickness)."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)
    region: Region = Field(
        description="Boundary edges with both vertices inside this region (initial positions) are loaded."
    )
    traction: list[float] = Field(
        min_length=3,
        max_length=3,
        description="Dead-load traction [Pa]: force per initial edge-face area (edge length x thickness), "
        "constant in direction and size; a shear P [N] spread over an end of width b: P / (b thickness).",
    )
    ramp_time: float = Field(
        0.0,
        ge=0,
        description="Time [s] over which the traction grows linearly from zero to its value (then held); "
        "0: applied in full from the start. A slow ramp with light, damped vertices gives a quasi-static "
        "load path (a static analysis by load steps).",
    )


class PinMotion(BaseModel):
    """A prescribed rigid motion of the vertices held by one `fixed` region (constant velocities, as a
    collider's constant `motion`): x(t) = R(w t) (x0 - pivot) + pivot + linear_velocity t."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)
    linear_velocity: list[float] = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        min_length=3,
        max_length=3,
        description="Velocity [m/s] of the pivot.",
    )
    angular_velocity: list[float] = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        min_length=3,
        max_length=3,
        description="Angular velocity [rad/s] about the pivot (e.g. [3.14, 0, 0]: half a turn a second "
        "about x).",
    )
    pivot: list[float] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="Point the rotation is about at t = 0 [m]; default the centre of the region's held "
        "vertices.",
    )


class FEMCloth(_Solid):
    """Thin shell on a triangle mesh: StVK membrane in plane stress and Kirchhoff-Love bending from a
    discrete shape operator (mid-edge normals, libshell's MidedgeAverage; or the older quadratic / hinge
    model); backward Euler, IPC contact."""

    type: Literal["FEM.Cloth"]
    E: float = Field(1.0e6, gt=0, description="Young's modulus [Pa] of the membrane.")
    nu: float = Field(0.3, ge=0.0, lt=0.5, description="Poisson's ratio [-], in [0, 0.5).")
    rho: float = Field(
        200.0,
        gt=0,
        description="Density [kg/m^3]; area density rho x thickness [kg/m^2], lumped to vertices.",
    )
    thickness: float = Field(1.0e-3, gt=0, description="Shell thickness [m].")
    bending_stiffness: float | None = Field(
        None,
        ge=0,
        description="Bending stiffness D [N m] (default the plate value E thickness^3 / (12 (1 - nu^2))); "
        "0: no bending.",
    )
    bending_model: Literal["shape_operator", "quadratic"] = Field(
        "shape_operator",
        description="Bending discretisation. shape_operator: Kirchhoff-Love plate energy "
        "D/2 [(k1 + k2)^2 - 2 (1 - nu) k1 k2] per triangle from a discrete shape operator (mid-edge normals "
        "of the triangle and its three neighbours), both curvature invariants, any rest shape. quadratic: "
        "the older model, mean curvature only (Bergou et al. 2006) on a flat rest mesh, discrete-shell "
        "hinges on a curved one; cheaper (constant Hessian when flat) but free in twist and saddle modes.",
    )
    friction: float = Field(
        0.0,
        ge=0,
        description="Coulomb coefficient [-] of self-contact (lagged IPC friction); against colliders and "
        "walls their own friction applies.",
    )
    damping: float = Field(
        0.0,
        ge=0,
        description="Mass-proportional damping [1/s]: force -damping m v on every vertex (implicit).",
    )

    fixed_velocity: list[float] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="Velocity [m/s] of the vertices held by `fixed` (as PBD): they move on the path x0 + "
        "fixed_velocity t instead of staying put (default: pinned).",
    )
    fixed_motion: list[PinMotion] | None = Field(
        None,
        min_length=1,
        description="One rigid motion per `fixed` region, in order (or one for all): the held vertices "
        "follow it (e.g. two edges twisted in opposite senses). Prescribed positions are Dirichlet degrees "
        "of freedom of the implicit step; the continuous collision check limits their motion as the rest.",
    )

    boundary_conditions: list[ClothTraction] = Field(
        default_factory=list,
        description="Edge loads: dead-load tractions on the free edges inside a region (pinned vertices: "
        "entity.fixed).",
    )

    @property
    def D(self) -> float:
        if self.bending_stiffness is not None:
            return float(self.bending_stiffness)
        return self.E * self.thickness**3 / (12.0 * (1.0 - self.nu**2))


MATERIALS = (FEMCloth,)
