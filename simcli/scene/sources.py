"""The `emitters:` and `sinks:` scene keys (docs/SCENE_FORMAT.md section 5): pydantic models, the nozzle's
lattice (numpy) and the semantic checks made at validate time. No Taichi: ``simcli validate`` imports this.

An emitter is a nozzle (a Circle or a Rectangle; a segment in 2D) through which particles of one material
enter at ``speed`` along its ``normal`` between ``start`` and ``stop``; the particles of one cross-section
lie on a lattice of the material's particle spacing, a new layer entering each time the previous one has
moved one spacing (so that the liquid enters at its rest spacing and the flux is rho A speed). The emitter
is an output entity of its own (named like it). A sink is a Box: particles that enter it leave the
simulation.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from simcli.scene.materials import Material

NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_-]*$"
# material types an emitter can emit (families whose solver has an active particle count)
EMITTING_FAMILIES = ("MPM", "SPH", "PBD")
# muscle groups and fibres are per body, not per nozzle; cloth, rods and soft bodies are meshes, not particles
NOT_EMITTING = ("MPM.Muscle", "PBD.Cloth", "PBD.Elastic")
EMITTABLE = "MPM.* (not MPM.Muscle), SPH.Liquid, PBD.Liquid and PBD.Particle"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


def _name(v: str, what: str) -> str:
    if not re.match(NAME_PATTERN, v):
        raise ValueError(
            f"{what} names are letters, digits, _ and - and start with a letter or _ (an output group and "
            f"file name); got {v!r}"
        )
    return v


Vec = list[float]


class CircleNozzle(_Strict):
    type: Literal["Circle"]
    center: Vec = Field(description="Centre of the nozzle [m].")
    radius: float = Field(gt=0, description="Radius [m]; in 2D the half length of the segment.")
    normal: Vec = Field(description="Direction the particles leave in [-]; normalised on load.")


class RectangleNozzle(_Strict):
    type: Literal["Rectangle"]
    center: Vec = Field(description="Centre of the nozzle [m].")
    size: list[float] = Field(
        description="Side lengths [m]: [a, b] in 3D (a along the first in-plane axis, see docs), [a] in 2D "
        "(the segment's length)."
    )
    normal: Vec = Field(description="Direction the particles leave in [-]; normalised on load.")


Nozzle = Annotated[CircleNozzle | RectangleNozzle, Field(discriminator="type")]


class Emitter(_Strict):
    name: str = Field(
        json_schema_extra={"pattern": NAME_PATTERN},
        description="Unique name; the emitted particles are an output entity of this name (sim.h5 "
        "/entities/<name>, vtk/<name>.pvd) and /emitters/<name>/emitted_mass.",
    )
    material: Material = Field(
        description="Material of the emitted particles: MPM.* (not MPM.Muscle), SPH.Liquid, PBD.Liquid or "
        "PBD.Particle (3D). Its family's particle spacing sets the lattice."
    )
    shape: Nozzle = Field(description="The nozzle: Circle (radius) or Rectangle (size); a segment in 2D.")
    speed: float = Field(gt=0, description="Speed [m/s] along the nozzle's normal.")
    start: float = Field(0.0, ge=0, description="Time the emission starts [s].")
    stop: float | None = Field(None, gt=0, description="Time the emission stops [s] (default: never).")
    max_particles: int = Field(
        gt=0,
        description="Particles this emitter can emit over the run, reserved up front (inactive slots cost "
        "nothing per substep); reaching it stops the emitter with a warning. With reuse: true the "
        "particles alive at once from this emitter (a sink frees their slots).",
    )
    reuse: bool = Field(
        False,
        description="Reuse the slots of particles a sink removed (SPlisHSPlasH's emitters): the emitter "
        "runs as long as its live particles fit max_particles; each particle carries a unique `emission` "
        "number and its `birth_time` in the output. Default false: a slot is never reused, the particles "
        "keep the order they entered (DualSPHysics's ids) and existing scenes run as before.",
    )

    @field_validator("name")
    @classmethod
    def _nm(cls, v: str) -> str:
        return _name(v, "emitter")

    @property
    def family(self) -> str:
        return self.material.type.split(".")[0]


class BoxSink(_Strict):
    name: str = Field(
        json_schema_extra={"pattern": NAME_PATTERN},
        description="Unique name: sim.h5 /sinks/<name>/removed_mass.",
    )
    type: Literal["Box"]
    lower: Vec = Field(description="Lower corner [m].")
    upper: Vec = Field(description="Upper corner [m].")

    @field_validator("name")
    @classmethod
    def _nm(cls, v: str) -> str:
        return _name(v, "sink")


Sink = Annotated[BoxSink, Field(discriminator="type")]


class EmitterEntity:
    """What an emitter looks like to the solvers and writers: an entity with a name and a material, whose
    particles enter over time (``is_emitter``)."""

    is_emitter = True

    def __init__(self, em: Emitter) -> None:
        self.emitter = em
        self.name = em.name
        self.material = em.material
        self.morph = None
        self.fixed = None
        self.velocity = None

    @property
    def family(self) -> str:
        return self.material.type.split(".")[0]

    @property
    def fixed_regions(self) -> list:
        return []


# ------------------------------------------------------------------------------------ geometry


def nozzle_frame(normal, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit normal and (dim - 1) in-plane unit axes (rows) of a nozzle. 3D: the first axis is the normal
    crossed with the coordinate axis least aligned with it."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    if dim == 2:
        return n, np.array([[-n[1], n[0]]])
    e = np.zeros(3)
    e[int(np.argmin(np.abs(n)))] = 1.0
    a = np.cross(n, e)
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    return n, np.array([a, b])


def nozzle_area(shape, dim: int) -> float:
    """The nozzle's area [m^2] (its length [m] in 2D)."""
    if shape.type == "Circle":
        return 2.0 * shape.radius if dim == 2 else math.pi * shape.radius**2
    return float(np.prod(shape.size[: dim - 1]))


def nozzle_lattice(shape, dim: int, spacing: float) -> np.ndarray:
    """Offsets (k, dim) [m] from the nozzle's centre of one layer of particles: the points of a lattice of
    ``spacing`` in the nozzle's plane, cell-centred, inside the circle or rectangle (at least one)."""
    _n, axes = nozzle_frame(shape.normal, dim)
    if shape.type == "Circle":
        half = [shape.radius] * (dim - 1)
    else:
        half = [0.5 * s for s in shape.size[: dim - 1]]
    grids = []
    for h in half:
        m = max(1, int(round(2.0 * h / spacing)))
        grids.append((np.arange(m) - 0.5 * (m - 1)) * spacing)
    if dim == 2:
        uv = grids[0][:, None]
    else:
        uu, vv = np.meshgrid(grids[0], grids[1], indexing="ij")
        uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
    if shape.type == "Circle" and dim == 3:
        keep = np.einsum("ij,ij->i", uv, uv) <= shape.radius**2 + 1e-12
        uv = uv[keep] if keep.any() else np.zeros((1, 2))
    return uv @ axes


# ------------------------------------------------------------------------------------ checks


def _inside_collider(c, x: np.ndarray, dim: int) -> np.ndarray:
    """Whether points x (k, dim) lie inside collider c (numpy, the collider at its initial pose)."""
    if c.type == "Plane":
        nrm = np.asarray(c.normal[:dim], dtype=np.float64)
        return (x - np.asarray(c.point[:dim])) @ (nrm / np.linalg.norm(nrm)) < 0
    if c.type == "Box":
        return np.all((x > np.asarray(c.lower[:dim])) & (x < np.asarray(c.upper[:dim])), axis=1)
    if c.type == "Sphere":
        return np.linalg.norm(x - np.asarray(c.center[:dim]), axis=1) < c.radius
    if c.type == "Cylinder":
        ax = "xyz".index(c.axis)
        d = x - np.asarray(c.center[:dim])
        if dim == 2:  # a box in 2D: the axis in the plane, or a disk seen end-on
            if ax >= 2:
                return np.linalg.norm(d, axis=1) < c.radius
            other = 1 - ax
            return (np.abs(d[:, ax]) < 0.5 * c.height) & (np.abs(d[:, other]) < c.radius)
        radial = np.delete(d, ax, axis=1)
        return (np.abs(d[:, ax]) < 0.5 * c.height) & (np.linalg.norm(radial, axis=1) < c.radius)
    return np.zeros(len(x), bool)


def family_spacing_of(scene, family: str) -> float:
    """The particle spacing [m] an emitter of ``family`` emits at (the family's particle_size)."""
    if family == "MPM":
        return float(scene.solvers.mpm.spacing)
    return float(getattr(scene.solvers, family.lower()).particle_size)


def check_sources(scene, err) -> None:
    """Semantic checks of `emitters:` and `sinks:`; ``err(path, message)`` records an error at a scene
    path."""
    dim = scene.sim.dim
    lo, hi = (np.asarray(v, dtype=np.float64) for v in scene.domain.bounds(dim))
    if len(lo) != dim or len(hi) != dim:  # the domain's own check reports it
        return
    taken = {e.name: "an entity" for e in scene.entities}
    for i, em in enumerate(scene.emitters):
        base = ("emitters", i)
        if em.name in taken:
            err(
                base + ("name",),
                f"the name '{em.name}' is already used by {taken[em.name]}; names are unique",
            )
        taken.setdefault(em.name, f"emitters.{i}")
        t = em.material.type
        if em.family not in EMITTING_FAMILIES or t in NOT_EMITTING:
            err(
                base + ("material", "type"),
                f"{t} cannot be emitted in this version of simcli; emitters take {EMITTABLE} materials",
            )
            continue
        if em.stop is not None and em.stop <= em.start:
            err(base + ("stop",), f"stop {em.stop:g} s is not after start {em.start:g} s; make stop > start")
        sh = em.shape
        bad = False
        for key in ("center", "normal"):
            if len(getattr(sh, key)) != dim:
                err(base + ("shape", key), f"expected {dim} components for dim {dim}")
                bad = True
        if sh.type == "Rectangle" and len(sh.size) != dim - 1:
            err(
                base + ("shape", "size"),
                f"a Rectangle nozzle has {dim - 1} side length(s) in {dim}D ([a] in 2D: a segment, [a, b] "
                f"in 3D); got {len(sh.size)}",
            )
            bad = True
        if sh.type == "Rectangle" and any(s <= 0 for s in sh.size):
            err(base + ("shape", "size"), "side lengths must be > 0")
            bad = True
        if bad:
            continue
        if float(np.linalg.norm(sh.normal)) == 0.0:
            err(base + ("shape", "normal"), "the normal is zero; give the direction the particles leave in")
            continue
        sp = family_spacing_of(scene, em.family)
        pts = np.asarray(sh.center, dtype=np.float64) + nozzle_lattice(sh, dim, sp)
        out = [a for a in range(dim) if pts[:, a].min() < lo[a] or pts[:, a].max() > hi[a]]
        if out:
            err(
                base + ("shape",),
                f"emitter '{em.name}': its nozzle reaches outside the domain along "
                f"{', '.join('xyz'[a] for a in out)} (domain {_fmt(lo)}..{_fmt(hi)}); move it inside",
            )
            continue
        for k, c in enumerate(scene.colliders):
            if np.any(_inside_collider(c, pts, dim)):
                err(
                    base + ("shape",),
                    f"emitter '{em.name}': its nozzle lies inside colliders.{k} ({c.type}); move it out "
                    "of the collider",
                )
                break
        if em.reuse:
            _check_reuse(scene, em, base, len(pts), err)
    for i, s in enumerate(scene.sinks):
        base = ("sinks", i)
        if s.name in taken:
            err(base + ("name",), f"the name '{s.name}' is already used by {taken[s.name]}; names are unique")
        taken.setdefault(s.name, f"sinks.{i}")
        if len(s.lower) != dim or len(s.upper) != dim:
            err(base, f"lower and upper need {dim} components for dim {dim}")
            continue
        a, b = np.asarray(s.lower, float), np.asarray(s.upper, float)
        if np.any(b <= a):
            err(base + ("upper",), "upper must be above lower on every axis")
            continue
        if np.any(b <= lo) or np.any(a >= hi):
            err(
                base,
                f"sink '{s.name}' {_fmt(a)}..{_fmt(b)} lies outside the domain {_fmt(lo)}..{_fmt(hi)}; move "
                "it so that it overlaps the domain",
            )
    if scene.sinks:
        fams = {e.family for e in scene.entities}  # (an emitter of another family is refused above)
        other = sorted(fams - set(EMITTING_FAMILIES))
        if other:
            err(
                ("sinks",),
                f"sinks remove MPM, SPH and PBD particles; this scene also has {', '.join(other)} entities, "
                "which a sink would not remove. Remove the sinks or those entities",
            )


def _check_reuse(scene, em, base, npl: int, err) -> None:
    """``reuse: true``: something must free slots (a sink), and one layer must fit the capacity (an emission
    takes whole layers of free slots)."""
    if not scene.sinks:
        err(
            base + ("reuse",),
            f"emitter '{em.name}': reuse: true reuses the slots of particles a sink removed, and this "
            "scene has no sinks, so no slot would ever be freed; add a sink (sinks: [{name, type: Box, "
            "lower, upper}]) or remove reuse",
        )
    if em.max_particles < npl:
        err(
            base + ("max_particles",),
            f"emitter '{em.name}': with reuse: true each emission takes a whole layer of {npl} free slots, "
            f"and max_particles = {em.max_particles} holds none; raise max_particles to at least {npl} "
            "(a few times the particles alive at once)",
        )


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"


def emitter_bodies(scene) -> list:
    """One Body per emitter: its ``max_particles`` reserved slots and one fresh row (see
    simcli/solvers/sources.py), parked at the nozzle's centre; the solver sets their mass when they
    enter."""
    from simcli.geometry.body import Body

    dim = int(scene.sim.dim)
    out = []
    for em in getattr(scene, "emitters", []):
        n = int(em.max_particles) + 1
        x = np.tile(np.asarray(em.shape.center, dtype=np.float64), (n, 1))
        z = np.zeros(n)
        out.append(
            Body(
                name=em.name,
                entity=EmitterEntity(em),
                x=x,
                v=np.zeros((n, dim)),
                volume=z,
                mass=z,
                fixed=np.zeros(n, bool),
            )
        )
    return out
