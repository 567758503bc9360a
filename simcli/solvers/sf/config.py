"""Stable-fluids configuration: solver options, the ``SF.Smoke`` material and jets (pydantic, no
Taichi).

The kernel half lives in ``grid.py`` (layout), ``advection.py``, ``jets.py``, ``boundary.py``,
``diffusion.py``, ``projection.py`` and ``solver.py``.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from simcli.scene.material_base import _Material

Vec = list[float]


class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class SFOptions(_Options):
    resolution: int | list[int] = Field(
        64,
        description="Grid cells along the longest axis of the domain [-] (cells are cubes as nearly as the "
        "domain allows: each axis gets round(length / dx) cells, dx = longest length / resolution), or a "
        "list with the number of cells along each axis.",
    )
    advection: Literal["semi_lagrangian", "maccormack", "bfecc"] = Field(
        "maccormack",
        description="Advection scheme. semi_lagrangian: Stam (1999), RK3 back-trace and (bi/tri)linear "
        "interpolation, first order and diffusive; maccormack: Selle et al. (2008) MacCormack step with "
        "their limiter (falls back to semi-Lagrangian where the corrected value leaves the range of the "
        "interpolation stencil), second order in smooth flow; bfecc: back-and-forth error compensation "
        "(Kim et al. 2005) with the same limiter, one more interpolation pass than maccormack.",
    )
    reflection: bool = Field(
        False,
        description="Advection-reflection (Zehnder, Narain & Thomaszewski 2018): each substep advects and "
        "projects over dt/2, reflects the velocity about the divergence-free space (subtracts the pressure "
        "gradient a second time), then advects and projects over dt/2 again. Loses far less kinetic energy "
        "to the advect/project splitting than Stam's step (whose loss grows with dt), at about twice the "
        "cost.",
    )
    pressure_solver: Literal["jacobi", "mgpcg"] = Field(
        "mgpcg",
        description="Pressure Poisson solver. jacobi: Jacobi iteration as in Stam (1999); mgpcg: conjugate "
        "gradient preconditioned with one geometric multigrid V-cycle (McAdams et al. 2010), which needs far "
        "fewer iterations. Both start from the previous step's pressure and stop on `tolerance`.",
    )
    tolerance: float = Field(
        1.0e-5,
        ge=0,
        description="Stop the pressure solve when the largest cell divergence after projection times the "
        "substep, max |div u| dt [-], is at or below this: the largest relative volume change of a cell per "
        "substep. 0 = off; with relative_tolerance also 0, exactly max_iterations run (Genesis's fixed-count "
        "Jacobi).",
    )
    relative_tolerance: float = Field(
        0.0,
        ge=0,
        description="Also stop the pressure solve when the residual 2-norm is at or below this fraction of "
        "the right-hand side's, ||r|| / ||div u*|| [-] (the share of the step's divergence left; comparable "
        "across discretisations). 0 = off.",
    )
    max_iterations: int = Field(
        2000,
        ge=1,
        description="Largest number of pressure iterations per substep (Jacobi sweeps or CG steps).",
    )
    check_every: int = Field(
        10,
        ge=1,
        description="Jacobi only: test the tolerance every this many sweeps (each test reads one number back "
        "from the device). MGPCG tests after every iteration.",
    )
    smoothing: int = Field(
        2,
        ge=1,
        le=8,
        description="MGPCG: red-black Gauss-Seidel sweeps before and after each coarse correction.",
    )
    viscosity_tolerance: float = Field(
        1.0e-6,
        gt=0,
        description="Implicit viscosity: stop conjugate gradients when the residual 2-norm falls below this "
        "fraction of the right-hand side's [-].",
    )
    cfl: float = Field(
        1.0,
        gt=0,
        description="CFL number (largest speed x substep / cell size) that `sim.substeps: auto` aims at [-]. "
        "Semi-Lagrangian advection is stable at any CFL number; larger steps only cost accuracy.",
    )
    max_cfl: float = Field(
        50.0,
        gt=0,
        description="A substep whose CFL number exceeds this is reported as a blow-up (exit 70) [-].",
    )
    steady_tolerance: float = Field(
        0.0,
        ge=0,
        description="Stop the run at steady state: after each written frame, the largest change of any face "
        "velocity since the previous frame divided by the time between them [m/s^2]; the run ends (status "
        "done, run.json stopped_steady) once it is at or below this. The run's duration (or steps) is the "
        "cap. 0 = off.",
    )

    def cells(self, lower: list[float], upper: list[float]) -> tuple[list[int], list[float]]:
        """Cells per axis and cell size per axis [m] over the box lower-upper."""
        ext = [float(h) - float(lo) for lo, h in zip(lower, upper)]
        if isinstance(self.resolution, list):
            if len(self.resolution) != len(ext):
                raise ValueError(f"solvers.sf.resolution needs {len(ext)} entries (one per axis)")
            n = [int(r) for r in self.resolution]
        else:
            dx = max(ext) / self.resolution
            n = [max(1, round(e / dx)) for e in ext]
        return n, [e / c for e, c in zip(ext, n)]

    @model_validator(mode="after")
    def _check(self):
        res = self.resolution if isinstance(self.resolution, list) else [self.resolution]
        if not res or any(r < 2 for r in res):
            raise ValueError("solvers.sf.resolution must be >= 2 cells (on every axis)")
        return self


# ------------------------------------------------------------------------------ material


class SFSmoke(_Material):
    """The fluid filling the whole domain grid: air carrying smoke density and temperature."""

    type: Literal["SF.Smoke"]
    viscosity: float = Field(
        0.0,
        ge=0,
        description="Kinematic viscosity nu [m^2/s] (air 1.5e-5; Reynolds number = U L / nu), solved "
        "implicitly (backward Euler), so any value is stable. 0 = inviscid (only the scheme's numerical "
        "viscosity).",
    )
    rho: float = Field(
        1.0,
        gt=0,
        description="Density of the fluid [kg/m^3] (air 1.2); only scales the pressure output [Pa].",
    )
    decay: float = Field(0.0, ge=0, description="Exponential decay rate of the smoke density [1/s].")
    cooling: float = Field(
        0.0,
        ge=0,
        description="Exponential relaxation rate of the temperature towards ambient_temperature [1/s].",
    )
    buoyancy: float = Field(
        0.0,
        description="Weight of the smoke alpha [-] (Boussinesq): a cell of smoke density s is pulled along "
        "gravity with the acceleration alpha s g (Fedkiw et al. 2001). Positive: smoke heavier than the air; "
        "negative: lighter.",
    )
    thermal_expansion: float = Field(
        1.0 / 293.15,
        ge=0,
        description="Thermal expansion coefficient beta [1/K] (Boussinesq): a cell at temperature T rises "
        "with the acceleration -beta (T - ambient_temperature) g. Default: an ideal gas at 20 C (1/293.15).",
    )
    ambient_temperature: float = Field(293.15, gt=0, description="Temperature of the air at rest [K].")
    vorticity_confinement: float = Field(
        0.0,
        ge=0,
        description="Vorticity confinement epsilon [-] (Fedkiw et al. 2001): adds epsilon dx (N x omega), N "
        "the unit gradient of |omega|, to restore small swirls the grid damps. 0 = off.",
    )
    initial_density: float = Field(
        1.0, ge=0, description="Smoke density [-] inside the entity's morph at t = 0 (0 elsewhere)."
    )
    initial_temperature: float | None = Field(
        None,
        gt=0,
        description="Temperature [K] inside the entity's morph at t = 0 (default ambient_temperature).",
    )


# ------------------------------------------------------------------------------ jets


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


_AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


def _rotation(axis: str, angle: float, dim: int) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    if dim == 2:
        return np.array([[c, -s], [s, c]])
    k = _AXES[axis]
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * kx + (1.0 - c) * (kx @ kx)  # Rodrigues


class OrbitPath(_Strict):
    type: Literal["orbit"]
    center: Vec = Field(description="Point on the rotation axis [m].")
    axis: Literal["x", "y", "z"] = Field(
        "z", description="Rotation axis (3D; in 2D the rotation is in the plane)."
    )
    angular_velocity: float = Field(description="Angular velocity [rad/s] (right-handed about the axis).")

    def at(self, p0: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position at time t and the rotation that turns the jet's vectors with it."""
        R = _rotation(self.axis, self.angular_velocity * t, len(p0))
        c = np.asarray(self.center, dtype=np.float64)
        return c + R @ (p0 - c), R


class WaypointPath(_Strict):
    type: Literal["waypoints"]
    times: Vec = Field(description="Times [s], strictly increasing.")
    points: list[Vec] = Field(
        description="Jet centre [m] at each time; piecewise linear between, held outside."
    )
    periodic: bool = Field(False, description="Repeat the path with period times[-1] - times[0].")

    @model_validator(mode="after")
    def _check(self):
        if len(self.times) != len(self.points) or not self.times:
            raise ValueError("times and points need the same, non-zero length")
        if any(b <= a for a, b in zip(self.times, self.times[1:])):
            raise ValueError("times must be strictly increasing")
        if self.periodic and len(self.times) < 2:
            raise ValueError("a periodic path needs at least two points")
        return self

    def at(self, p0: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        ts = self.times
        if self.periodic:
            t = ts[0] + math.fmod(t - ts[0], ts[-1] - ts[0])
            if t < ts[0]:
                t += ts[-1] - ts[0]
        pts = np.asarray(self.points, dtype=np.float64)
        eye = np.eye(pts.shape[1])
        if t <= ts[0]:
            return pts[0], eye
        if t >= ts[-1]:
            return pts[-1], eye
        k = int(np.searchsorted(ts, t, side="right")) - 1
        a = (t - ts[k]) / (ts[k + 1] - ts[k])
        return (1.0 - a) * pts[k] + a * pts[k + 1], eye


JetPath = Annotated[OrbitPath | WaypointPath, Field(discriminator="type")]


class Jet(_Strict):
    """A source: inside a ball of `radius` around the (possibly moving) centre, the fluid is driven to
    `velocity` and/or accelerated by `force`, and smoke and heat are added."""

    position: Vec | None = Field(
        None, description="Centre of the jet at t = 0 [m] (required unless the path is 'waypoints')."
    )
    radius: float = Field(gt=0, description="Radius of the ball the jet acts in [m] (a disk in 2D).")
    velocity: Vec | None = Field(
        None,
        description="Velocity the fluid inside the jet is set to [m/s] (an inlet); on an orbit it "
        "turns with the jet.",
    )
    force: Vec | None = Field(
        None,
        description="Acceleration added inside the jet [m/s^2] (Genesis's inlet impulse); on an orbit it "
        "turns with the jet.",
    )
    density_rate: float = Field(0.0, ge=0, description="Smoke density added per second inside the jet [1/s].")
    temperature_rate: float = Field(0.0, description="Temperature added per second inside the jet [K/s].")
    start: float = Field(0.0, ge=0, description="The jet acts from this time [s].")
    stop: float | None = Field(None, gt=0, description="... until this time [s] (default: the whole run).")
    path: JetPath | None = Field(
        None,
        description="Motion of the centre: 'orbit' about an axis (starting at `position`) or "
        "'waypoints' (times and points, piecewise linear). None: fixed at `position`.",
    )

    @model_validator(mode="after")
    def _check(self):
        if self.position is None and not (self.path is not None and self.path.type == "waypoints"):
            raise ValueError("give the jet's position (or a waypoints path)")
        if self.stop is not None and self.stop <= self.start:
            raise ValueError("stop must be after start")
        return self

    def vectors(self) -> dict[str, Vec | None]:
        return {
            "position": self.position,
            "velocity": self.velocity,
            "force": self.force,
            "path.center": getattr(self.path, "center", None),
        }

    def state(self, t: float, dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """(centre [m], velocity [m/s], force [m/s^2], on: 1.0 or 0.0) at time t, host side."""
        p0 = np.asarray(self.position if self.position is not None else self.path.points[0], dtype=np.float64)
        v = np.asarray(self.velocity if self.velocity is not None else [0.0] * dim, dtype=np.float64)
        f = np.asarray(self.force if self.force is not None else [0.0] * dim, dtype=np.float64)
        if self.path is None:
            p, R = p0, np.eye(dim)
        else:
            p, R = self.path.at(p0, t)
        on = 1.0 if (t >= self.start and (self.stop is None or t < self.stop)) else 0.0
        return p, R @ v, R @ f, on


# Every SF material type; the scene's material union is built from these.
MATERIALS = (SFSmoke,)


# ------------------------------------------------------------------------------ memory


def estimate_bytes(opts: SFOptions, mat: SFSmoke | None, n: list[int], precision: str = "f32") -> int:
    """Bytes of memory the SF solver allocates for a grid of n cells per axis (before it does)."""
    dim = len(n)
    fp = 8 if precision == "f64" else 4
    cells = math.prod(c + 2 for c in n)
    faces = math.prod(c + 3 for c in n)
    n_tmp = {"semi_lagrangian": 1, "bfecc": 2, "maccormack": 4}[opts.advection]
    # velocity and its advection scratch (copies, MacCormack's limiter range), the node velocities
    per_face = dim * (1 + n_tmp) + dim
    # smoke density and temperature with their scratch; pressure, phi, rhs, diagonal and the solver's
    # vectors (CG r, z, p, Ap or Jacobi's second copy); the coarser multigrid levels (phi, rhs, diagonal)
    per_cell = 2 * (1 + n_tmp) + 4 + (4 if opts.pressure_solver == "mgpcg" else 1)
    per_cell += 3 * (1 / 7 if dim == 3 else 1 / 3)
    if mat is not None and mat.viscosity > 0:
        per_face += dim * 5  # diagonal, boundary values, CG r, p, Ap per component
    if mat is not None and mat.vorticity_confinement > 0:
        per_cell += (3 if dim == 3 else 1) + dim
    # MGPCG keeps phi in f64
    per_cell += (8 // fp - 1) if opts.pressure_solver == "mgpcg" else 0
    device = (
        per_face * faces * fp + per_cell * cells * fp + (dim + 1) * faces
    )  # + face kinds, cell flags (u8)
    # host: the build's float64 layout arrays, or a frame's output copies (velocity, pressure, scalars and
    # divergence in float64 plus their float32 copies), whichever is larger; and Taichi's runtime
    host = max(3 * dim, 2 * dim + 6) * cells * 8 + (256 << 20)
    return int(device + host)
