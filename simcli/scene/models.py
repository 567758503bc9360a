"""The scene schema: frozen pydantic models, validated without importing Taichi.

Every field carries a description with its SI unit; the JSON Schema in ``schemas/`` is
generated from these models (``simcli schema``).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from simcli.probes.config import Probe
from simcli.rigid.config import RigidBody
from simcli.scene.materials import Material
from simcli.scene.morphs import Morph, Region
from simcli.scene.sources import Emitter, Sink
from simcli.solvers.fem.config import FEMOptions
from simcli.solvers.mpm.config import MPMOptions
from simcli.solvers.pbd.config import PBDOptions
from simcli.solvers.sf.config import Jet, SFOptions
from simcli.solvers.sph.config import SPHOptions

FACES = ("x-", "x+", "y-", "y+", "z-", "z+")

Vec = list[float]


class Strict(BaseModel):
    """Base for every scene model: unknown keys are errors, models are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


# --------------------------------------------------------------------------- sim


class Sim(Strict):
    dim: Literal[2, 3] = Field(3, description="Spatial dimension: 2 or 3.")
    dt: float = Field(2.0e-3, gt=0, description="Step [s]; frames are written on step boundaries.")
    substeps: Annotated[int, Field(ge=1)] | Literal["auto"] = Field(
        10,
        description="Substeps per step (integer >= 1), or 'auto': the largest stable substep from the "
        "CFL and elastic wave-speed limits, chosen every frame.",
    )
    auto_check: Literal["frame", "substep"] = Field(
        "frame",
        description="With substeps: auto, how often the stable substep is re-evaluated. frame: once per "
        "output frame, and every step of the frame is split into that many equal substeps (a step's substep "
        "count is the smallest that keeps each within the limit). substep: before every substep, from the "
        "state at that moment, as SPlisHSPlasH's adaptive step; each substep is as large as the limits "
        "allow, and the last ones of a step are made equal so that the step ends on its boundary (use a long "
        "sim.dt, e.g. the output interval, so that few substeps are shortened). Costs one reduction per "
        "substep.",
    )
    duration: float | None = Field(
        None, gt=0, description="Simulated time [s]. Give duration or steps, not both (default 1 s)."
    )
    steps: int | None = Field(
        None, ge=1, description="Number of steps to run. Give duration or steps, not both."
    )
    gravity: Vec | None = Field(
        None,
        description="Gravitational acceleration [m/s^2], one component per dimension. Default: -9.81 along "
        "the last axis.",
    )
    precision: Literal["f32", "f64"] = Field("f32", description="Floating-point precision of the kernels.")
    backend: Literal["auto", "cpu", "gpu", "cuda", "vulkan", "metal"] = Field(
        "auto", description="Compute backend; auto = a GPU if present, else cpu."
    )
    threads: int | None = Field(
        None, ge=1, description="CPU threads for the cpu backend (default: all cores the process may use)."
    )
    seed: int = Field(0, description="Random seed (jittered sampling, ...).")

    @model_validator(mode="after")
    def _check(self):
        if self.duration is not None and self.steps is not None:
            raise ValueError("give sim.duration or sim.steps, not both")
        if self.auto_check == "substep" and self.substeps != "auto":
            raise ValueError(
                f"sim.auto_check: substep needs sim.substeps: auto (got substeps: {self.substeps}); "
                "remove auto_check or set substeps: auto"
            )
        if self.gravity is not None and len(self.gravity) != self.dim:
            raise ValueError(
                f"sim.gravity must have {self.dim} components for dim {self.dim} (got {len(self.gravity)})"
            )
        return self

    @property
    def gravity_vec(self) -> list[float]:
        if self.gravity is not None:
            return list(self.gravity)
        return [0.0] * (self.dim - 1) + [-9.81]

    @property
    def n_steps(self) -> int:
        if self.steps is not None:
            return self.steps
        duration = 1.0 if self.duration is None else self.duration
        return max(1, int(round(duration / self.dt)))


# ------------------------------------------------------------------------ domain


class Boundary(Strict):
    type: Literal["slip", "sticky", "separate", "open", "periodic"] = Field(
        "slip",
        description="slip: normal velocity zeroed, tangential kept (minus Coulomb friction); sticky: all "
        "velocity zeroed (or set to the face velocity); separate: like slip but only when moving into the "
        "wall. Grid fluids (SF) only: open (outflow: zero pressure on the face, fluid leaves or enters "
        "freely); periodic (leaving through this face re-enters through the opposite one; give both faces of "
        "an axis).",
    )
    friction: float = Field(
        0.0,
        ge=0,
        description="Coulomb friction coefficient [-]. MPM: friction > 0 makes a slip face unilateral like "
        "separate (material may leave it; Coulomb friction needs a compressive contact).",
    )
    velocity: Vec | None = Field(
        None, description="Wall velocity [m/s] (a moving lid); one component per dimension."
    )


class Domain(Strict):
    lower: Vec | None = Field(
        None,
        description="Lower corner of the simulation box [m]. Default (-0.5, -0.5, 0) in 3D, (0, 0) in 2D.",
    )
    upper: Vec | None = Field(
        None, description="Upper corner of the simulation box [m]. Default (0.5, 0.5, 1) in 3D, (1, 1) in 2D."
    )
    boundary: Boundary = Field(default_factory=Boundary, description="Wall condition on every face.")
    faces: dict[Literal["x-", "x+", "y-", "y+", "z-", "z+"], Boundary] = Field(
        default_factory=dict, description="Per-face overrides of `boundary` (faces x-, x+, y-, y+, z-, z+)."
    )

    def bounds(self, dim: int) -> tuple[list[float], list[float]]:
        lo = self.lower if self.lower is not None else ([-0.5, -0.5, 0.0] if dim == 3 else [0.0, 0.0])
        hi = self.upper if self.upper is not None else ([0.5, 0.5, 1.0] if dim == 3 else [1.0, 1.0])
        return list(lo), list(hi)

    def face(self, name: str) -> Boundary:
        return self.faces.get(name, self.boundary)


# --------------------------------------------------------------------- colliders


class Keyframes(Strict):
    times: list[float] = Field(min_length=1, description="Key times [s], increasing.")
    translate: list[Vec] | None = Field(
        None, description="Translation [m] of the collider at each key time (default: none)."
    )
    rotate: list[Vec] | None = Field(
        None,
        description="Rotation about the pivot at each key time: XYZ Euler angles [deg] (R = Rz Ry Rx); "
        "interpolated as quaternions. 2D: one angle about z.",
    )


class Motion(Strict):
    linear_velocity: Vec | None = Field(None, description="Constant velocity [m/s].")
    angular_velocity: Vec | None = Field(
        None, description="Constant angular velocity [rad/s] about `pivot` (2D: one component, about z)."
    )
    pivot: Vec | None = Field(
        None,
        description="Point the rotation is about, at t = 0 [m]; default the collider's centre (a "
        "Plane's point).",
    )
    keyframes: Keyframes | None = Field(
        None,
        description="Piecewise linear translation and rotation, held before the first and after the "
        "last key.",
    )
    file: str | None = Field(
        None,
        description="CSV file (relative to the scene) with columns t, x, y, z, qw, qx, qy, qz: "
        "translation [m] "
        "and unit quaternion of the rotation about the pivot, piecewise linear.",
    )

    @model_validator(mode="after")
    def _one_kind(self):
        const = self.linear_velocity is not None or self.angular_velocity is not None
        kinds = [
            k for k, on in (("constant", const), ("keyframes", self.keyframes), ("file", self.file)) if on
        ]
        if len(kinds) > 1:
            raise ValueError(
                f"give one of linear_velocity/angular_velocity, keyframes or file (got {' and '.join(kinds)})"
            )
        if not kinds:
            raise ValueError("give linear_velocity and/or angular_velocity, keyframes or file")
        return self


class _ColliderBase(Strict):
    name: str | None = Field(
        None,
        description="Name, unique among colliders: named colliders report the force and torque the materials "
        "exert on them (sim.h5 /colliders/<name>/force, /torque).",
    )
    motion: Motion | None = Field(
        None,
        description="Prescribed rigid motion (default: the collider stands still). MPM, PBD and FEM scenes.",
    )
    boundary: Literal["slip", "sticky", "separate"] = Field(
        "separate", description="Contact condition on the collider surface (see domain.boundary.type)."
    )
    friction: float = Field(
        0.0,
        ge=0,
        description="Coulomb friction coefficient [-]. MPM: friction > 0 makes a slip collider unilateral "
        "like separate (Coulomb friction needs a compressive contact).",
    )
    restitution: float = Field(
        0.0,
        ge=0,
        le=1,
        description="Normal restitution [-], 0..1: a particle or vertex hitting the collider leaves it with "
        "restitution x its normal approach speed (relative to the surface). PBD particles, FEM (explicit) "
        "vertices, MPM particles pushed out of the collider (the MPM grid contact stays inelastic; "
        "docs/SCENE_FORMAT.md section 5). 0 (default): perfectly inelastic, as before.",
    )


_CPIC_DOC = (
    "MPM: Compatible Particle-In-Cell (Hu et al. 2018) for this collider: a particle and a grid node on "
    "opposite sides of it exchange nothing, so a plate thinner than the kernel's support cuts the material "
    "cleanly (docs/MPM.md, CPIC). Default off."
)


class PlaneCollider(_ColliderBase):
    type: Literal["Plane"]
    point: Vec = Field(description="A point on the plane [m].")
    normal: Vec = Field(description="Outward normal (towards the free side) [-]; normalised on load.")
    cpic: bool = Field(False, description=_CPIC_DOC)


class BoxCollider(_ColliderBase):
    type: Literal["Box"]
    lower: Vec = Field(description="Lower corner [m].")
    upper: Vec = Field(description="Upper corner [m].")
    cpic: bool = Field(False, description=_CPIC_DOC + " A Box is a plate along its thinnest axis.")


class SphereCollider(_ColliderBase):
    type: Literal["Sphere"]
    center: Vec = Field(description="Centre [m] (a disk in 2D).")
    radius: float = Field(gt=0, description="Radius [m].")


class CylinderCollider(_ColliderBase):
    type: Literal["Cylinder"]
    center: Vec = Field(description="Centre of the cylinder's axis segment [m].")
    radius: float = Field(gt=0, description="Radius [m].")
    height: float = Field(gt=0, description="Length along the axis [m].")
    axis: Literal["x", "y", "z"] = Field("z", description="Axis direction.")


class MeshCollider(_ColliderBase):
    type: Literal["Mesh"]
    file: str = Field(
        description="Closed, consistently oriented triangle surface (any format meshio reads), relative to "
        "the scene file; 3D only. Turned into a signed-distance grid at build time."
    )
    scale: float | Vec = Field(1.0, description="Scale factor [-] (scalar or per axis), applied first.")
    rotate: Vec = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        description="Rotation: Euler angles x, y, z [deg] (R = Rz Ry Rx), applied second.",
    )
    translate: Vec = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        description="Translation [m], applied last; also the default pivot of `motion` (the file's origin).",
    )
    sdf_cell: float | None = Field(
        None,
        gt=0,
        description="Cell [m] of the signed-distance grid (default: half the finest of the MPM grid cell, "
        "the PBD and SPH particle_size, the FEM element size 1/resolution and the SF cell of the families "
        "present).",
    )


Collider = Annotated[
    PlaneCollider | BoxCollider | SphereCollider | CylinderCollider | MeshCollider,
    Field(discriminator="type"),
]


# ----------------------------------------------------------------------- solvers


class Solvers(Strict):
    mpm: MPMOptions = Field(default_factory=MPMOptions, description="MPM solver options.")
    sph: SPHOptions = Field(
        default_factory=SPHOptions, description="SPH solver options (WCSPH / DFSPH liquids)."
    )
    sf: SFOptions = Field(
        default_factory=SFOptions, description="Stable-fluids grid solver options (SF.Smoke)."
    )
    fem: FEMOptions = Field(
        default_factory=FEMOptions, description="FEM solver options (tetrahedral solids)."
    )
    pbd: PBDOptions = Field(
        default_factory=PBDOptions, description="PBD solver options (XPBD cloth and rods)."
    )


# ---------------------------------------------------------------------- entities


class Entity(Strict):
    name: str = Field(description="Unique name; names the output groups and files.", min_length=1)
    material: Material = Field(description="Material; its `type` selects the solver family and model.")
    morph: Morph | None = Field(
        None,
        description="Initial shape. Required for every family except SF, where it is optional and marks "
        "where smoke starts (the SF fluid fills the whole domain).",
    )
    velocity: Vec | None = Field(None, description="Initial velocity [m/s], one component per dimension.")
    fixed: Region | list[Region] | None = Field(
        None, description="Region (or list of regions): particles/vertices inside are held in place."
    )
    jets: list[Jet] = Field(
        default_factory=list,
        description="SF only: sources of smoke, heat and momentum (a ball each, fixed or moving on a path).",
    )
    velocity_field: list[str] | None = Field(
        None,
        description="SF and SPH: initial velocity [m/s], one numpy expression of x, y[, z] [m] per component "
        "(e.g. ['sin(x) * cos(y)', '-cos(x) * sin(y)']; pi, sin, cos, exp, sqrt, tanh, abs, where), added to "
        "`velocity`.",
    )

    @model_validator(mode="after")
    def _check_family(self):
        fam = self.family
        if fam != "SF":
            if self.morph is None:
                raise ValueError(
                    f"morph is required for {self.material.type} entities (only SF.Smoke entities "
                    "may omit it)"
                )
            if self.jets:
                raise ValueError(f"jets are for SF.Smoke entities only (this one is {self.material.type})")
            if self.velocity_field is not None and fam != "SPH":
                raise ValueError(
                    f"velocity_field is for SF.Smoke and SPH entities only (this one is {self.material.type})"
                )
        elif self.fixed is not None:
            raise ValueError("fixed regions are not available for SF.Smoke entities (use colliders)")
        return self

    @property
    def family(self) -> str:
        if self.material.type == "FEM.Cloth":  # thin shells: a solver of their own (simcli.solvers.fem.cloth)
            return "FEMCloth"
        return self.material.type.split(".")[0]

    @property
    def fixed_regions(self) -> list:
        if self.fixed is None:
            return []
        return list(self.fixed) if isinstance(self.fixed, list) else [self.fixed]


# ------------------------------------------------------------------------ output


class Output(Strict):
    dir: str | None = Field(
        None, description="Output folder, relative to the working directory (default out/<scene name>)."
    )
    every: int = Field(5, ge=1, description="Write a frame every N steps (frame 0 is the initial state).")
    formats: list[Literal["hdf5", "vtk"]] = Field(
        default_factory=lambda: ["hdf5", "vtk"], description="Output formats: hdf5 (sim.h5 + sim.xdmf), vtk."
    )
    fields: Literal["default"] | list[str] = Field(
        "default",
        description="Per-particle fields to write: 'default' (position, velocity) or a list from position, "
        "velocity, J, stress (von Mises [Pa]), material_id (MPM); position, velocity, density [kg/m^3], "
        "pressure [Pa], material_id (SPH); position, velocity, displacement [m], reaction (force of the "
        "supports on pinned vertices [N]), density [kg/m^3] (PBD); position, velocity, displacement [m], "
        "mass (lumped vertex mass [kg]), strain, stress [Pa] (FEM.Cloth).",
    )


class Checkpoint(Strict):
    every: int = Field(0, ge=0, description="Steps between checkpoints; 0 = only on interruption.")
    keep: int = Field(2, ge=1, description="Number of newest checkpoints kept.")


# ------------------------------------------------------------------------- scene


class Coupling(Strict):
    """Forces between entities of different families (docs/COUPLING.md). Every pair of families present in the
    scene is coupled unless its key is false; a key for a pair that is not present is a warning."""

    mpm_sph: bool = Field(
        True,
        description="MPM <-> SPH (two-way, momentum conserving): in 3D, MPM solids (Elastic, "
        "ElastoPlastic, Snow, Muscle; no MPM emitter or sink, none pinned) as SPH boundary particles "
        "(Akinci et al. 2012: samples on SPH's lattice moved by MPM's grid, the liquid's pressure impulse "
        "back to its nodes); otherwise (2D, sand, liquid, solvers.sph.boundary: volume_map) a contact on the "
        "MPM grid.",
    )
    mpm_pbd: bool = Field(
        True, description="MPM <-> PBD: contact on the MPM grid (two-way, momentum conserving)."
    )
    mpm_fem: bool = Field(
        True,
        description="MPM <-> FEM: FEM vertices in a contact on the MPM grid (two-way, momentum conserving).",
    )
    sph_pbd: bool = Field(
        True,
        description="SPH <-> PBD: contact on a background grid of the pair's own (two-way, momentum "
        "conserving).",
    )
    sph_fem: bool = Field(
        True,
        description="SPH <-> FEM: the FEM body's samples as SPH boundary particles (Akinci et al. 2012, "
        "two-way, momentum conserving: the liquid's pressure impulse on each sample goes to its "
        "tetrahedron's corners); with solvers.sph.boundary: volume_map a contact on a background grid of "
        "the pair's own.",
    )
    pbd_fem: bool = Field(
        True,
        description="PBD <-> FEM: contact on a background grid of the pair's own (two-way, momentum "
        "conserving).",
    )


class Scene(Strict):
    version: Literal[1] = Field(1, description="Scene format version.")
    name: str | None = Field(None, description="Scene name; default: the file name without extension.")
    sim: Sim = Field(default_factory=Sim, description="Time stepping, dimension, precision and backend.")
    domain: Domain = Field(default_factory=Domain, description="The box every solver lives in [m].")
    colliders: list[Collider] = Field(
        default_factory=list, description="Rigid obstacles, still or in prescribed motion."
    )
    rigid_bodies: list[RigidBody] = Field(
        default_factory=list,
        description="Free rigid bodies (Box, Sphere, Cylinder), two-way coupled with MPM, PBD, FEM and SPH "
        "entities through the moving-collider path; sim.h5 /rigid_bodies/<name>/....",
    )
    solvers: Solvers = Field(default_factory=Solvers, description="Options per solver family.")
    entities: list[Entity] = Field(default_factory=list, description="Simulated bodies.")
    output: Output = Field(default_factory=Output, description="What is written, where and how often.")
    checkpoint: Checkpoint = Field(default_factory=Checkpoint, description="Restart files.")
    coupling: Coupling | None = Field(
        None,
        description="Coupling between families: every pair present is coupled by default; `<pair>: false` "
        "turns one off.",
    )
    probes: list[Probe] = Field(
        default_factory=list,
        description="Time series measured while the run goes (point, height gauge, total), sampled every N "
        "steps, written to OUT/probes.csv and sim.h5 /probes/<name>/time, /value.",
    )
    emitters: list[Emitter] = Field(
        default_factory=list,
        description="Nozzles through which particles enter over time (MPM.*, SPH.Liquid); each is an output "
        "entity of its name.",
    )
    sinks: list[Sink] = Field(
        default_factory=list, description="Regions (Box) whose particles leave the simulation (MPM, SPH)."
    )

    @property
    def families(self) -> set[str]:
        return {e.family for e in self.entities} | {em.family for em in self.emitters}


def resolved_scene_dict(scene: Scene, name: str) -> dict:
    """The scene with every default filled in (what ``OUT/scene.yaml`` echoes)."""
    d = scene.model_dump(mode="json")
    dim = scene.sim.dim
    d["name"] = name
    d["sim"]["gravity"] = scene.sim.gravity_vec
    if scene.sim.steps is None:
        d["sim"]["duration"] = 1.0 if scene.sim.duration is None else scene.sim.duration
    lo, hi = scene.domain.bounds(dim)
    d["domain"]["lower"], d["domain"]["upper"] = lo, hi
    d["solvers"]["mpm"]["particle_size"] = scene.solvers.mpm.spacing
    for c in d["colliders"]:  # scenes without named or moving colliders echo as before
        for key in ("name", "motion"):
            if c.get(key) is None:
                c.pop(key, None)
        if c.get("cpic") is False:  # (so a run checkpointed before CPIC existed resumes)
            c.pop("cpic")
    for em in d.get("emitters") or []:  # the same for emitters before slot reuse existed
        if em.get("reuse") is False:
            em.pop("reuse")
    # the sand yield surface and fit actually used (yield_surface: auto resolves by dimension; so a 2D run
    # checkpointed when the default was drucker_prager resumes, and a 3D one does not silently change law)
    for given, echoed in zip(
        [*scene.entities, *scene.emitters], [*d["entities"], *(d.get("emitters") or [])], strict=True
    ):
        if hasattr(given.material, "resolved"):
            used = given.material.resolved(dim)
            echoed["material"]["yield_surface"] = used.yield_surface
            echoed["material"]["cone"] = used.cone
    if not d.get("rigid_bodies"):  # scenes without rigid bodies echo as before
        d.pop("rigid_bodies", None)
    for rb in d.get("rigid_bodies") or []:  # (and those without CPIC bodies: runs checkpointed before resume)
        if rb.get("cpic") is False:
            rb.pop("cpic")
    if d.get("coupling") is None:  # scenes without the key echo as before
        d.pop("coupling", None)
    d["output"]["dir"] = scene.output.dir if scene.output.dir is not None else f"out/{name}"
    return d
