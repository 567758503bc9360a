"""PBD configuration: solver options and materials (pydantic, no Taichi).

Names follow Genesis (``gs.options.PBDOptions``, ``gs.materials.PBD.Cloth``): ``stretch_compliance``,
``bending_compliance``, ``rho``, ``air_resistance``, ``static_friction``/``kinetic_friction``.
Where simcli differs it says so in the field's description: the compliances are XPBD compliances
(inverse stiffness, the same for any iteration count and substep), there is no ``*_relaxation``
(XPBD needs none), and iteration counts are options of the solver, as in Genesis.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from simcli.scene.material_base import _Material

Vec = list[float]


class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class PBDOptions(_Options):
    particle_size: float = Field(
        0.01,
        gt=0,
        description="Particle diameter [m]: the contact thickness of cloth vertices against colliders and "
        "walls (half of it on each side of the sheet).",
    )
    stretch_iterations: int = Field(
        4,
        ge=1,
        description="Gauss-Seidel sweeps over the stretch (distance) constraints per substep (Genesis: "
        "max_stretch_solver_iterations).",
    )
    bending_iterations: int = Field(
        1,
        ge=1,
        description="Gauss-Seidel sweeps over the bending constraints per substep (Genesis: "
        "max_bending_solver_iterations).",
    )
    density_iterations: int = Field(
        4,
        ge=1,
        description="PBD.Liquid: density-constraint iterations per substep (Genesis: "
        "max_density_solver_iterations).",
    )
    liquid_walls: bool = Field(
        True,
        description="PBD.Liquid: the domain walls count in the density as the particle lattice mirrored "
        "behind them (without it a particle next to a wall misses neighbours and the liquid packs against "
        "the walls).",
    )
    tet_resolution: float = Field(
        20.0,
        gt=0,
        description="PBD.Elastic soft bodies: cells per metre of the tetrahedralisation (as FEM's "
        "resolution: Box morphs split each cell into 6 tets; other solids get tets of about that size).",
    )
    collisions: bool = Field(
        True,
        description="Particle-particle contact between PBD vertices and particles (cloth self-collision, "
        "bodies against each other) at a distance of the two radii (particle_size for cloth), with Coulomb "
        "friction; vertices of one body closer than that in the rest shape are exempt.",
    )


class _PBDBase(_Material):
    static_friction: float = Field(
        0.15,
        ge=0,
        description="Static Coulomb friction coefficient [-] of "
        "particle-particle contact (the larger of the two vertices' applies).",
    )
    kinetic_friction: float = Field(
        0.15, ge=0, description="Kinetic Coulomb friction coefficient [-] of particle-particle contact."
    )
    air_resistance: float = Field(
        0.0,
        ge=0,
        description="Linear air drag rate [1/s]: each substep velocities are multiplied by "
        "exp(-air_resistance dt). (Genesis's air_resistance is a force coefficient [N s/m] per particle.)",
    )


class _PBDMaterial(_PBDBase):
    fixed_velocity: Vec | None = Field(
        None,
        description="Velocity [m/s] of the vertices held by `fixed`: they move on the path x0 + "
        "fixed_velocity t instead of staying put (default: pinned).",
    )
    stretch_compliance: float = Field(
        1.0e-7,
        ge=0,
        description="XPBD compliance of the stretch (distance) constraints [m/N]: the inverse of "
        "an edge's spring stiffness; 0 = inextensible.",
    )
    bending_compliance: float | None = Field(
        1.0e-5,
        ge=0,
        description="XPBD compliance of the bending constraints: [1/(N m)] for cloth (dihedral "
        "angle in rad), [m/N] for rods (distance between every other vertex); null: no bending constraints "
        "(a chain).",
    )


class PBDCloth(_PBDMaterial):
    """Triangle-mesh cloth: stretch constraints on edges, dihedral bending constraints on interior edges
    (rest angle from the rest mesh)."""

    type: Literal["PBD.Cloth"]
    rho: float = Field(
        4.0,
        gt=0,
        description="Surface density [kg/m^2]; vertex mass = rho x a third of the area of its triangles.",
    )


class PBDElastic(_PBDMaterial):
    """Rods and chains from `Line` morphs: stretch constraints on segments, bending constraints between
    every other vertex (rest distance from the rest polyline). Soft bodies from Box, Sphere, Cylinder and
    Mesh morphs, tetrahedralised as for FEM: stretch constraints on the tet edges and a volume constraint
    per tet."""

    type: Literal["PBD.Elastic"]
    rho: float = Field(
        1000.0,
        gt=0,
        description="Density [kg/m^3]; a rod's mass is rho x pi radius^2 x length, "
        "shared equally by its vertices; a soft body's vertex gets a quarter of each adjacent "
        "tet's mass.",
    )
    volume_compliance: float = Field(
        0.0,
        ge=0,
        description="Soft bodies: XPBD compliance of the tet volume constraints C = V - V0 [m^5/N] "
        "(energy C^2 / (2 compliance)); 0 = incompressible.",
    )
    initial_stretch: Vec | None = Field(
        None,
        description="Start deformed: initial vertex positions scaled by these factors [-] per axis about "
        "the body's centroid, the rest shape unchanged (a stretched spring released).",
    )


class PBDParticle(_PBDBase):
    """Particles that only collide (granular crowds): the morph is filled with a lattice of spacing
    solvers.pbd.particle_size; contact with each other, walls and colliders, with Coulomb friction."""

    type: Literal["PBD.Particle"]
    rho: float = Field(
        1000.0, gt=0, description="Density [kg/m^3]; particle mass = rho x morph volume / particle count."
    )


class PBDLiquid(_PBDBase):
    """Position-based fluid (Macklin and Mueller 2013): density constraints with the artificial pressure
    term, XSPH viscosity. The morph is filled with a lattice of spacing solvers.pbd.particle_size."""

    type: Literal["PBD.Liquid"]
    rho: float = Field(
        1000.0,
        gt=0,
        description="Density [kg/m^3]; particle mass = rho x morph volume / "
        "particle count (Genesis sets each particle's mass to rho). The rest density of the "
        "constraint is the kernel sum of the initial lattice, so the block starts at rest.",
    )
    density_relaxation: float = Field(
        0.2,
        gt=0,
        description="Constraint force mixing eps of the density constraint, relative to an interior "
        "particle's sum |grad C|^2 [-] (Macklin and Mueller's eps; larger = softer, more stable).",
    )
    viscosity_relaxation: float = Field(
        0.01, ge=0, description="XSPH viscosity coefficient c [-]: v_i += c sum_j V_j (v_j - v_i) W_ij."
    )
    vorticity_confinement: float = Field(
        0.0,
        ge=0,
        description="Vorticity confinement epsilon [m/s] (Macklin and Mueller's eq. 16): acceleration "
        "epsilon (N x omega), N the unit gradient of |omega|; 0 = off.",
    )
    artificial_pressure: float = Field(
        1.0e-4,
        ge=0,
        description="k of the artificial pressure s_corr = -k (W(r) / W(0.2 h))^4 / S0 [-] (Macklin and "
        "Mueller's eq. 13, here relative to an interior particle's sum |grad C|^2 S0). It is a position "
        "offset per iteration, so its velocity grows as 1 / substep: Macklin's k = 0.1 (for a 1/60 s step) "
        "blows a 0.2 ms-substep column apart.",
    )


# Every PBD material type; the scene's material union is built from these.
MATERIALS = (PBDCloth, PBDElastic, PBDParticle, PBDLiquid)

MORPHS = {
    "PBD.Cloth": ("Rectangle", "Mesh"),
    "PBD.Elastic": ("Line", "Box", "Sphere", "Cylinder", "Mesh"),
    "PBD.Particle": ("Box", "Sphere", "Cylinder", "Mesh"),
    "PBD.Liquid": ("Box", "Sphere", "Cylinder", "Mesh"),
}


# PBD materials that run in 2D scenes (free particles: the liquid and the granular crowd, entities or emitted,
# and sinks); the meshed bodies (cloth, rods, soft bodies) and coupling with other families are 3D only.
MATERIALS_2D = ("PBD.Liquid", "PBD.Particle")
MORPHS_2D = ("Box", "Sphere")
# coupling keys of the pairs with PBD: 3D only (a pair turned off may share a 2D scene)
COUPLED_2D = {"MPM": "mpm_pbd", "SPH": "sph_pbd", "FEM": "pbd_fem"}


def check_2d(e, scene) -> list[tuple[tuple, str]]:
    """What a 2D scene refuses of a PBD entity (path below the entity, message): the 3D-only materials and
    morphs; with ``scene``, the coupling with other families (3D only in this version)."""
    t = e.material.type
    if t not in MATERIALS_2D:
        return [
            (
                ("material", "type"),
                f"{t} is 3D only (sim.dim: 3); in 2D, PBD runs {' and '.join(MATERIALS_2D)} "
                "(cloth, rods and soft bodies are 3D only)",
            )
        ]
    if e.morph.type not in MORPHS_2D:
        return [
            (
                ("morph", "type"),
                f"{t} in 2D takes {' or '.join(MORPHS_2D)} morphs (a Sphere is a disk); got {e.morph.type}",
            )
        ]
    out: list[tuple[tuple, str]] = []
    if scene is None:
        return out
    cfg = getattr(scene, "coupling", None)
    fams = sorted(set(scene.families) & set(COUPLED_2D))  # entities and emitters alike
    for fam in fams:
        key = COUPLED_2D[fam]
        if cfg is None or bool(getattr(cfg, key)):
            out.append(
                (
                    ("material", "type"),
                    f"{t}: coupling PBD with {fam} is 3D only; this 2D scene has {fam} entities or "
                    f"emitters: use sim.dim: 3, or set coupling.{key}: false (they then do not interact)",
                )
            )
    return out


def check_entity(e, dim: int, scene_dir, lo, hi, opts=None, scene=None) -> list[tuple[tuple, str]]:
    """Semantic checks of a PBD entity: (path below the entity, message) per problem. ``scene``: the whole
    scene (2D: coupling with other families is 3D only)."""
    out: list[tuple[tuple, str]] = []
    m = e.morph
    if dim not in (2, 3):
        return [(("material", "type"), f"{e.material.type} entities need sim.dim 2 or 3")]
    if dim == 2:
        found = check_2d(e, scene)
        if found:
            return found
    allowed = MORPHS.get(e.material.type, ())
    if m.type not in allowed:
        what = {
            "PBD.Cloth": "cloth is a Rectangle or a triangle Mesh",
            "PBD.Elastic": "rods are Line morphs, soft bodies solids",
            "PBD.Particle": "a solid shape filled with particles",
            "PBD.Liquid": "a solid shape filled with particles",
        }.get(e.material.type, "")
        return [
            (
                ("morph", "type"),
                f"{e.material.type} takes {' or '.join(allowed)} morphs ({what}); got {m.type}",
            )
        ]
    for j, r in enumerate(e.fixed_regions):
        rpath = ("fixed",) + ((j,) if isinstance(e.fixed, list) else ())
        if dim == 2 and r.type == "Cylinder":
            out.append((rpath + ("type",), "Cylinder regions need dim 3 (use a Box or Sphere in 2D)"))
            continue
        for f in ("lower", "upper", "center", "size"):
            v = getattr(r, f, None)
            if v is not None and len(v) != dim:
                out.append((rpath + (f,), f"expected {dim} components for dim {dim} (got {len(v)})"))
    for f in ("lower", "upper", "size") if m.type == "Box" else ():
        v = getattr(m, f, None)
        if v is not None and len(v) != dim:
            out.append((("morph", f), f"expected {dim} components for dim {dim} (got {len(v)})"))
    if m.type in ("Rectangle", "Sphere", "Cylinder") and len(m.center) != dim:
        out.append((("morph", "center"), f"expected {dim} components for dim {dim} (got {len(m.center)})"))
    if m.type == "Line":
        if len(m.points[0]) != 3:
            out.append(
                (("morph", "points"), f"expected 3 components per point for dim 3 (got {len(m.points[0])})")
            )
        elif _polyline_length(m.points) <= 0:
            out.append((("morph", "points"), "the polyline has zero length"))
    fv = getattr(e.material, "fixed_velocity", None)
    if fv is not None and len(fv) != 3:
        out.append((("material", "fixed_velocity"), f"expected 3 components (got {len(fv)})"))
    if (
        e.material.type == "PBD.Elastic"
        and e.material.initial_stretch is not None
        and len(e.material.initial_stretch) != 3
    ):
        out.append((("material", "initial_stretch"), "expected 3 factors (x, y, z)"))
    if out:
        return out
    try:
        # validate never builds a large body: beyond VALIDATE_BUILD_LIMIT vertices only the counts (for the
        # memory estimate) and the bounds come from the morph; the run builds it after the estimate passed
        from simcli.solvers.pbd.resources import pbd_entity_counts

        opts = opts or PBDOptions()
        if pbd_entity_counts(e, opts, scene_dir, dim)[0] > VALIDATE_BUILD_LIMIT:
            x = _morph_extent(m, scene_dir)
        else:
            from simcli.solvers.pbd.topology import mesh_for_entity

            x = mesh_for_entity(e, scene_dir, opts, dim).x
    except Exception as ex:  # noqa: BLE001 - unreadable mesh file, no triangles, no tetgen: all reported
        return [(("morph",) + (("file",) if m.type == "Mesh" else ()), str(ex))]
    if lo is not None:
        bad = [a for a in range(dim) if x[:, a].min() < lo[a] - 1e-9 or x[:, a].max() > hi[a] + 1e-9]
        if bad:
            out.append(
                (
                    ("morph",),
                    (
                        f"entity '{e.name}' extends outside the domain along "
                        f"{', '.join('xyz'[a] for a in bad)}; move it or enlarge domain"
                    ),
                )
            )
    return out


# Bodies up to this many vertices or particles are built in `validate` (which then also reports a morph that
# gets no particles, or that TetGen cannot mesh); larger ones are checked from their bounds only.
VALIDATE_BUILD_LIMIT = 20_000


def _morph_extent(m, scene_dir):
    """Points spanning the morph's extent without building it: a Rectangle's corners, a Line's points,
    the bounding box of anything else (a Mesh's from its file)."""
    import numpy as np

    if m.type == "Rectangle":
        from simcli.solvers.pbd.topology import sheet_axes

        u, v, _ = sheet_axes(m.normal)
        c = np.asarray(m.center, dtype=np.float64)
        return np.array([c + 0.5 * (a * m.size[0] * u + b * m.size[1] * v) for a in (-1, 1) for b in (-1, 1)])
    if m.type == "Line":
        return np.asarray(m.points, dtype=np.float64)
    from simcli.geometry.sampling import morph_bounds

    return np.stack(morph_bounds(m, scene_dir))


def _polyline_length(points) -> float:
    import numpy as np

    p = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
