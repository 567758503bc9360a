"""The `probes:` scene key (docs/SCENE_FORMAT.md section 5): pydantic models and the semantic checks made at
validate time. No Taichi, no numpy-heavy work: ``simcli validate`` imports this.

A probe is a time series sampled every ``every`` steps (default: output.every):

* ``point``: pressure [Pa], velocity [m/s] or density [kg/m^3] at a point, a kernel-weighted average of
  the nearby particles (SPH: the SPH kernel and support radius; MPM, PBD: a cubic spline of radius two
  particle spacings) or a trilinear interpolation of the SF grid.
* ``height``: the free-surface height [m] along ``axis`` of the particles in a column of radius one particle
  spacing through ``position`` (the coordinates along the other axes): the highest particle plus half a
  spacing (``surface: connected``: the highest one connected to the column's bottom without a gap wider than
  the particles' reach, SPH's support radius or three MPM cells; spray left out).
* ``total``: kinetic_energy [J], elastic_energy [J] (MPM, FEM), mass [kg], momentum [kg m/s] or com [m] of one
  entity or of every entity (``"*"``).
"""

from __future__ import annotations

import re
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_-]*$"

# What each family can answer (entity material types where a family answers only for some)
POINT_FAMILIES = {
    "pressure": ("SPH", "MPM", "SF"),
    "velocity": ("SPH", "MPM", "PBD", "SF"),
    "density": ("SPH", "MPM", "PBD"),
}
# PBD entities that are particles (not cloth, rods or tet meshes): the ones point probes and gauges read
PBD_PARTICLE_TYPES = ("PBD.Liquid", "PBD.Particle")
PBD_DENSITY_TYPES = ("PBD.Liquid",)
HEIGHT_FAMILIES = ("SPH", "MPM", "PBD")
TOTAL_FAMILIES = {
    "kinetic_energy": ("MPM", "SPH", "PBD", "FEM"),
    "mass": ("MPM", "SPH", "PBD", "FEM"),
    "momentum": ("MPM", "SPH", "PBD", "FEM"),
    "com": ("MPM", "SPH", "PBD", "FEM"),
    "elastic_energy": ("MPM", "FEM"),
}
UNITS = {
    "pressure": "Pa",
    "velocity": "m/s",
    "density": "kg/m^3",
    "height": "m",
    "kinetic_energy": "J",
    "elastic_energy": "J",
    "mass": "kg",
    "momentum": "kg m/s",
    "com": "m",
}
VECTOR_QUANTITIES = ("velocity", "momentum", "com")


class _Probe(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)

    name: str = Field(
        json_schema_extra={"pattern": NAME_PATTERN},
        description="Unique name (letters, digits, _ and -): the column of probes.csv and /probes/<name> in "
        "sim.h5.",
    )
    every: int | None = Field(
        None, ge=1, description="Sample every N steps (step 0 included); default: output.every."
    )

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not re.match(NAME_PATTERN, v):
            raise ValueError(
                f"probe names are letters, digits, _ and - and start with a letter or _ (a column "
                f"of probes.csv, "
                f"a group of sim.h5); got {v!r}"
            )
        return v


class PointProbe(_Probe):
    type: Literal["point"]
    quantity: Literal["pressure", "velocity", "density"] = Field(
        description="pressure [Pa] (SPH, MPM, SF), velocity [m/s] (SPH, MPM, PBD.Liquid/Particle, "
        "SF) or density "
        "[kg/m^3] (SPH, MPM, PBD.Liquid) at the point: a kernel-weighted average of the particles "
        "within reach "
        "(SPH: the SPH kernel and support radius; MPM, PBD: a cubic spline of radius 2 particle "
        "spacings), or "
        "the SF grid interpolated trilinearly. NaN while no particle is within reach (a dry point)."
    )
    position: list[float] = Field(
        description="The point [m], one component per dimension; inside the domain."
    )
    entity: str = Field(
        "*", description="Entity read, or '*' (default): every entity whose family answers the quantity."
    )


class HeightProbe(_Probe):
    type: Literal["height"]
    position: list[float] = Field(
        description="Coordinates [m] of the gauge along the axes other than `axis`, in x, y, z "
        "order ([x, y] in "
        "3D with axis z, [x] in 2D with axis y); inside the domain."
    )
    axis: Literal["x", "y", "z"] | None = Field(
        None,
        description="The vertical axis the height is measured along (default: the last, z in 3D, y in 2D).",
    )
    entity: str = Field(
        "*",
        description="Entity read (any SPH, MPM, PBD.Liquid or PBD.Particle entity), or '*' "
        "(default): every liquid "
        "(SPH.Liquid, MPM.Liquid, PBD.Liquid). The "
        "height [m] is the coordinate of the highest particle within one particle spacing of the "
        "gauge's line "
        "plus half a spacing; NaN while the column is dry.",
    )
    surface: Literal["highest", "connected"] = Field(
        "highest",
        description="highest (default): the highest particle in the column. connected: the top of the "
        "liquid connected to the column's lowest particle, the particles taken from the bottom up to the "
        "first gap along `axis` wider than the distance over which two particles still act on each other "
        "(SPH: the kernel's support radius; MPM: three grid cells; PBD: two particle sizes), so that spray "
        "and droplets above the liquid are not the surface (as a wave gauge's wire reads it).",
    )


class TotalProbe(_Probe):
    type: Literal["total"]
    quantity: Literal["kinetic_energy", "elastic_energy", "mass", "momentum", "com"] = Field(
        description="kinetic_energy [J], mass [kg], momentum [kg m/s] (dim components), com (centre "
        "of mass [m], dim "
        "components) of MPM, SPH, PBD and FEM entities; elastic_energy [J] of MPM and FEM entities (per "
        "metre of depth "
        "in 2D)."
    )
    entity: str = Field("*", description="Entity name, or '*' (default): every entity that carries mass.")


Probe = Annotated[PointProbe | HeightProbe | TotalProbe, Field(discriminator="type")]


# --------------------------------------------------------------------------- helpers (no Taichi)


def probe_every(probe, output_every: int) -> int:
    return probe.every if probe.every is not None else output_every


def height_axis(probe: HeightProbe, dim: int) -> int:
    return "xyz".index(probe.axis) if probe.axis is not None else dim - 1


def components(probe, dim: int) -> int:
    q = "height" if probe.type == "height" else probe.quantity
    return dim if q in VECTOR_QUANTITIES else 1


def quantity(probe) -> str:
    return "height" if probe.type == "height" else probe.quantity


def answers(entity, probe) -> bool:
    """Whether ``entity`` (a scene Entity) can answer ``probe``."""
    fam, mtype = entity.family, entity.material.type
    if probe.type == "point":
        if fam not in POINT_FAMILIES[probe.quantity]:
            return False
        if fam == "PBD":
            return mtype in (PBD_DENSITY_TYPES if probe.quantity == "density" else PBD_PARTICLE_TYPES)
        return True
    if probe.type == "height":
        return fam in HEIGHT_FAMILIES and (fam != "PBD" or mtype in PBD_PARTICLE_TYPES)
    return fam in TOTAL_FAMILIES[probe.quantity]


LIQUID_TYPES = ("SPH.Liquid", "MPM.Liquid", "PBD.Liquid")


def default_entity(entity, probe) -> bool:
    """Whether ``entity: "*"`` includes ``entity``: every entity that answers, except that a height gauge
    reads
    the liquids only (a floating block or a sand heap is read by naming it)."""
    if probe.type == "height":
        return entity.material.type in LIQUID_TYPES
    return answers(entity, probe)


def _who_answers(probe) -> str:
    if probe.type == "point":
        fams = POINT_FAMILIES[probe.quantity]
        names = [
            f if f != "PBD" else "PBD.Liquid" if probe.quantity == "density" else "PBD.Liquid/Particle"
            for f in fams
        ]
        return ", ".join(names)
    if probe.type == "height":
        return "SPH, MPM, PBD.Liquid/Particle"
    return ", ".join(TOTAL_FAMILIES[probe.quantity])


def all_entities(scene) -> list:
    """The scene's entities and its emitters (each an entity of its own name, simcli/scene/sources.py)."""
    from simcli.scene.sources import EmitterEntity

    return list(scene.entities) + [EmitterEntity(em) for em in getattr(scene, "emitters", [])]


def probe_entities(scene, probe) -> list:
    """The scene entities a probe reads (after check_probes has passed)."""
    if probe.entity != "*":
        return [e for e in all_entities(scene) if e.name == probe.entity]
    ents = [e for e in all_entities(scene) if default_entity(e, probe)]
    if probe.type == "point" and any(e.family == "SF" for e in ents) and len(ents) > 1:
        return []  # refused by check_probes
    return ents


def check_probes(scene, err) -> None:
    """Semantic checks of `probes:`; ``err(path, message)`` records an error at a scene path."""
    dim = scene.sim.dim
    lo, hi = scene.domain.bounds(dim)
    if len(lo) != dim or len(hi) != dim:
        return
    seen: dict[str, int] = {}
    names = {e.name: e for e in all_entities(scene)}
    for i, p in enumerate(scene.probes):
        base = ("probes", i)
        if p.name in seen:
            err(
                base + ("name",),
                f"duplicate probe name '{p.name}' (also probes.{seen[p.name]}.name); names must be unique",
            )
        else:
            seen[p.name] = i
        # position
        if p.type == "point":
            if len(p.position) != dim:
                err(base + ("position",), f"expected {dim} components for dim {dim} (got {len(p.position)})")
            else:
                out = [a for a in range(dim) if not lo[a] <= p.position[a] <= hi[a]]
                if out:
                    err(
                        base + ("position",),
                        f"probe '{p.name}' at {_fmt(p.position)} is outside the domain "
                        f"{_fmt(lo)}..{_fmt(hi)} "
                        f"along {', '.join('xyz'[a] for a in out)}; move it inside",
                    )
        elif p.type == "height":
            if p.axis is not None and "xyz".index(p.axis) >= dim:
                err(
                    base + ("axis",),
                    f"axis {p.axis} does not exist in {dim}D (x, y{', z' if dim == 3 else ''})",
                )
                continue
            ax = height_axis(p, dim)
            others = [a for a in range(dim) if a != ax]
            if len(p.position) != dim - 1:
                err(
                    base + ("position",),
                    f"a height gauge's position gives the {dim - 1} coordinate(s) along "
                    f"{', '.join('xyz'[a] for a in others)} (not along its axis {'xyz'[ax]}); got "
                    f"{len(p.position)}",
                )
            else:
                out = [a for a, c in zip(others, p.position) if not lo[a] <= c <= hi[a]]
                if out:
                    err(
                        base + ("position",),
                        f"height gauge '{p.name}' at {_fmt(p.position)} "
                        f"({', '.join('xyz'[a] for a in others)}) is "
                        f"outside the domain along {', '.join('xyz'[a] for a in out)} (domain "
                        f"{_fmt(lo)}..{_fmt(hi)}); "
                        "move it inside",
                    )
        # entity and quantity
        what = f"{quantity(p)} ({p.type} probe)"
        if p.entity != "*":
            e = names.get(p.entity)
            if e is None:
                known = ", ".join(sorted(names)) or "none"
                err(base + ("entity",), f"no entity named '{p.entity}' (entities: {known}; or '*' for all)")
                continue
            if not answers(e, p):
                err(
                    base + ("entity",),
                    f"entity '{p.entity}' ({e.material.type}) cannot answer {what}; entities that can: "
                    f"{_who_answers(p)}",
                )
            continue
        ents = [e for e in all_entities(scene) if default_entity(e, p)]
        if not ents and p.type == "height" and any(answers(e, p) for e in all_entities(scene)):
            err(
                base + ("entity",),
                "a height gauge reads the liquids (SPH.Liquid, MPM.Liquid, PBD.Liquid) unless it names an "
                "entity, and this scene has none; name the entity whose surface it measures with "
                "entity: <name>",
            )
        elif not ents:
            present = ", ".join(sorted({e.material.type for e in all_entities(scene)})) or "no entities"
            qpath = base + ("quantity",) if p.type != "height" else base + ("type",)
            err(
                qpath,
                f"no entity of this scene ({present}) can answer {what}; entities that can: "
                f"{_who_answers(p)}",
            )
        elif p.type == "point" and any(e.family == "SF" for e in ents) and len(ents) > 1:
            err(
                base + ("entity",),
                f"{what} would mix the SF grid with particles ({', '.join(e.name for e in ents)}); "
                f"name one with "
                "entity: <name>",
            )
        elif (
            p.type == "total"
            and p.quantity == "elastic_energy"
            and any(not answers(e, p) for e in all_entities(scene) if e.family != "SF")
        ):
            bad = [e.name for e in all_entities(scene) if e.family != "SF" and not answers(e, p)]
            err(
                base + ("quantity",),
                f"elastic_energy is available for MPM and FEM entities only, not for {', '.join(bad)}; "
                f"name an MPM or FEM entity "
                "with entity: <name>, or use kinetic_energy",
            )


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"
