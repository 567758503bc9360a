"""Morph -> particles: fill an entity's initial shape with particles on a lattice.

Plain numpy, no Taichi (runs before any solver is built).

Lattice
    A regular lattice of spacing ``h``, the family's particle spacing (MPM: ``solvers.mpm.spacing``,
    i.e. ``particle_size``, default 0.64 / grid_density; SPH: ``solvers.sph.particle_size``), centred
    on the shape's bounding box: along an
    axis of extent L it has ``n = max(1, floor(L / h + 1/2))`` points at
    ``centre + (i - (n - 1) / 2) h``, so it is symmetric within the shape and
    cell-centred when L is a multiple of h (a 0.2 m box at h = 0.01 m gets 20
    points per axis, 8000 particles in 3D). Points are at least h/4 inside a box's
    faces. Curved shapes (Sphere, Cylinder, Mesh) keep the lattice points of their
    bounding box that lie inside the shape (boundary included).

Jitter (``solvers.mpm.sampling: jitter``)
    Every point gets a uniform random offset in [-0.3 h, 0.3 h] per axis; a point
    whose jittered position would leave the shape keeps its lattice position, so
    the particle count does not depend on the seed and every particle is inside.

Poisson disk (``solvers.mpm.sampling: poisson``)
    Blue-noise points with a minimum distance r = 0.80 h (2D) or 0.87 h (3D): no lattice
    directions, for sand and snow whose lattice rows otherwise show as stripes and preferred failure
    planes. Dart throwing on a background grid of cells r / sqrt(d) wide (at most one point per
    cell), processed in 3^d phases of cells three apart, which cannot conflict, so each phase is
    one vectorised pass (the parallel scheme of Wei 2008, "Parallel Poisson disk sampling");
    ``POISSON_TRIALS`` passes. The count is about V / h^d (within a few %; it depends on the seed);
    points keep 0.15 h from the faces of analytic shapes (mesh shapes: inside the surface).

Mass and volume
    Each particle carries ``volume = V / n`` and ``mass = rho V / n``, where V is the
    shape's exact volume (analytic, or the mesh's enclosed volume from the
    divergence theorem) and n the particle count, so the total mass is exact even
    for curved shapes (Genesis uses h^3 per particle). In 2D "volume" is an area
    [m^2] and mass is per metre of thickness.

Dimensions
    3D: Box, Sphere, Cylinder (axis x, y or z), Mesh. 2D: Box, Sphere (a disk);
    Cylinder and Mesh raise ValueError.

Warnings
    ``sample_entity`` returns a ``Body`` with a ``warnings`` list (also logged at DEBUG level on the
    ``simcli.geometry`` logger): the body is under-resolved (n h^dim differs from V
    by more than 10 %), a part of a mesh thinner than the spacing got no particles,
    or a ``fixed`` region holds no particle. A shape thinner than the spacing may get
    no particles at all (n = 0, an empty Body); the caller decides what to do.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from simcli.geometry.body import Body
from simcli.geometry.mesh import (
    MeshError,
    MeshFileNotFoundError,
    TriMesh,
    lattice_inside_mesh,
    load_mesh_morph,
    mesh_bounds,
    points_inside_mesh,
)
from simcli.geometry.regions import check_shape_dim, points_in_regions, points_in_shape, shape_volume
from simcli.scene.morphs import BoxShape, CylinderShape, MeshShape, SphereShape

__all__ = [
    "JITTER",
    "UNDER_RESOLVED_TOL",
    "Body",
    "MeshError",
    "MeshFileNotFoundError",
    "entity_rng",
    "estimate_particle_count",
    "lattice_for_bounds",
    "morph_bounds",
    "morph_volume",
    "sample_entity",
    "sample_morph",
    "sample_scene",
]

log = logging.getLogger("simcli.geometry")

JITTER = 0.3  # jitter amplitude, in units of the spacing
UNDER_RESOLVED_TOL = 0.10  # warn when n h^dim differs from the body volume by more than this
MISSED_VOLUME_TOL = 0.01  # warn when mesh parts holding this fraction of the volume got no particles

PathLike = str | os.PathLike


# ------------------------------------------------------------------------ helpers


def _check_dim(morph, dim: int) -> None:
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    if isinstance(morph, MeshShape):
        if dim != 3:
            raise ValueError("Mesh morphs need a 3D scene (sim.dim: 3); use a Box or Sphere in 2D")
        return
    if isinstance(morph, (BoxShape, SphereShape, CylinderShape)):
        check_shape_dim(morph, dim)
        return
    raise ValueError(f"unsupported morph type: {getattr(morph, 'type', type(morph).__name__)}")


def lattice_for_bounds(lo, hi, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(origin, counts) of the lattice centred in the box [lo, hi]: point i is origin + spacing * i."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    h = float(spacing)
    if not h > 0:
        raise ValueError(f"particle spacing must be > 0, got {spacing}")
    counts = np.maximum(1, np.floor((hi - lo) / h + 0.5)).astype(np.int64)
    origin = 0.5 * (lo + hi) - 0.5 * (counts - 1) * h
    return origin, counts


def _lattice_points(origin: np.ndarray, counts: np.ndarray, h: float) -> np.ndarray:
    axes = [origin[a] + h * np.arange(counts[a]) for a in range(len(counts))]
    grids = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.reshape(-1) for g in grids], axis=1)


def morph_bounds(morph, scene_dir: PathLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners [m] of the morph's axis-aligned bounding box.

    Analytic shapes: from their parameters (as many components as given). Mesh: the
    bounding box of the transformed vertices (reads the file; raises MeshError).
    """
    if isinstance(morph, MeshShape):
        return mesh_bounds(morph, scene_dir)
    lo, hi = morph.bounds()
    return np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)


def morph_volume(morph, dim: int, scene_dir: PathLike | None = None) -> float:
    """Exact volume [m^3] (area [m^2] in 2D) of the morph."""
    _check_dim(morph, dim)
    if isinstance(morph, MeshShape):
        return load_mesh_morph(morph, scene_dir).volume
    return shape_volume(morph, dim)


def estimate_particle_count(morph, spacing: float, dim: int, scene_dir: PathLike | None = None) -> int:
    """Particle count estimate without sampling: exact for a Box, volume / spacing^dim otherwise."""
    _check_dim(morph, dim)
    if isinstance(morph, BoxShape):
        lo, hi = morph.bounds()
        return int(np.prod(lattice_for_bounds(lo, hi, spacing)[1]))
    return round(morph_volume(morph, dim, scene_dir) / float(spacing) ** dim)


# ----------------------------------------------------------------------- sampling


def _as_rng(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(rng)


def sample_morph(
    morph,
    spacing: float,
    dim: int,
    scene_dir: PathLike | None = None,
    jitter: bool = False,
    rng=None,
    poisson: bool = False,
    thin_layer: bool = False,
) -> tuple[np.ndarray, float, list[str]]:
    """Particle positions (n, dim) filling the morph, the morph's exact volume, and warnings."""
    _check_dim(morph, dim)
    h = float(spacing)
    warnings: list[str] = []
    mesh: TriMesh | None = None
    if poisson:
        x, volume = _poisson_fill(morph, h, dim, scene_dir, _as_rng(rng))
        jitter = False
    elif isinstance(morph, MeshShape):
        mesh = load_mesh_morph(morph, scene_dir)
        volume = mesh.volume
        lo, hi = mesh.bounds
        origin, counts = lattice_for_bounds(lo, hi, h)
        res = lattice_inside_mesh(mesh, origin, h, counts)
        idx = np.nonzero(res.inside)
        x = origin + h * np.stack(idx, axis=1).astype(np.float64)
        warnings += res.warnings
        thin = _thin_layer(res.thin_points, h) if thin_layer else np.zeros((0, 3))
        if len(thin):
            x = np.concatenate([x, thin])
        if res.missed_volume > MISSED_VOLUME_TOL * volume:
            if thin_layer:
                warnings.append(
                    f"mesh '{morph.file}': parts thinner than the particle spacing ({h:g} m), about "
                    f"{100 * res.missed_volume / volume:.1f}% of the volume, got one layer of {len(thin)} "
                    "particles on their mid-surface; lower particle_size to resolve them"
                )
            else:
                warnings.append(
                    f"mesh '{morph.file}': parts thinner than the particle spacing ({h:g} m) got no "
                    f"particles (about {100 * res.missed_volume / volume:.1f}% of the volume, "
                    f"{res.missed_volume:.3g} m^3); their mass is carried by the other particles; lower "
                    "particle_size to resolve them, or set solvers.mpm.thin_parts: layer to give them one "
                    "layer of particles"
                )
    else:
        volume = shape_volume(morph, dim)
        lo, hi = morph.bounds()
        origin, counts = lattice_for_bounds(lo, hi, h)
        x = _lattice_points(origin, counts, h)
        if not isinstance(morph, BoxShape):  # a box's lattice lies inside it by construction
            x = x[points_in_shape(morph, x)]

    if jitter and x.shape[0]:
        gen = _as_rng(rng)
        xj = x + gen.uniform(-JITTER * h, JITTER * h, size=x.shape)
        ok = points_inside_mesh(mesh, xj, bin_size=h) if mesh is not None else points_in_shape(morph, xj)
        x = np.where(ok[:, None], xj, x)

    n = x.shape[0]
    if n:
        sampled = n * h**dim
        dev = sampled / volume - 1.0
        if abs(dev) > UNDER_RESOLVED_TOL:
            warnings.append(
                f"{morph.type} is coarsely resolved: {n} particles x spacing^{dim} = {sampled:.3g} vs its "
                f"volume {volume:.3g} ({100 * dev:+.0f}%); particle masses are scaled so the total mass is "
                "exact, but consider a smaller particle_size"
            )
    return x, float(volume), warnings


_FIELD_NAMES = {
    "np": np,
    "pi": np.pi,
    "sin": np.sin,
    "cos": np.cos,
    "exp": np.exp,
    "sqrt": np.sqrt,
    "tanh": np.tanh,
    "abs": np.abs,
    "where": np.where,
    "minimum": np.minimum,
    "maximum": np.maximum,
}


def velocity_field(entity, x: np.ndarray) -> np.ndarray:
    """The entity's ``velocity_field`` (numpy expressions of x, y[, z]) at the particles ``x`` (n, dim); zeros
    when it has none."""
    exprs = getattr(entity, "velocity_field", None)
    if not exprs:
        return np.zeros_like(x)
    env = {**_FIELD_NAMES, **dict(zip("xyz", x.T))}
    cols = [
        np.broadcast_to(np.asarray(eval(e, {"__builtins__": {}}, env), dtype=np.float64), (len(x),))
        for e in exprs
    ]  # restricted names, no builtins
    return np.stack(cols, axis=1)


def sample_entity(entity, scene, scene_dir: PathLike | None = None, rng=None) -> Body:
    """Fill one entity's morph with particles and return its initial state as a Body.

    ``rng``: a numpy Generator (or a seed) for jittered sampling; unused on a plain lattice.
    The returned Body has a ``warnings`` list of strings (see the module docstring).
    """
    dim = scene.sim.dim
    mpm = scene.solvers.mpm
    jitter = entity.family == "MPM" and getattr(mpm, "sampling", "lattice") == "jitter"
    poisson = entity.family == "MPM" and getattr(mpm, "sampling", "lattice") == "poisson"
    thin_layer = entity.family == "MPM" and getattr(mpm, "thin_parts", "warn") == "layer"
    if (jitter or poisson) and rng is None:
        rng = scene.sim.seed
    try:
        x, volume, warnings = sample_morph(
            entity.morph,
            family_spacing(scene, entity.family),
            dim,
            scene_dir,
            jitter=jitter,
            rng=rng,
            poisson=poisson,
            thin_layer=thin_layer,
        )
    except MeshFileNotFoundError as exc:
        raise MeshFileNotFoundError(f"entity '{entity.name}': {exc}") from None
    except MeshError as exc:
        raise MeshError(f"entity '{entity.name}': {exc}") from None
    except ValueError as exc:
        raise ValueError(f"entity '{entity.name}': {exc}") from None
    n = x.shape[0]
    rho = float(entity.material.rho)
    per_volume = volume / n if n else 0.0

    if entity.velocity is not None:
        vel = np.asarray(entity.velocity, dtype=np.float64)
        if vel.shape != (dim,):
            raise ValueError(
                f"entity '{entity.name}': velocity has {vel.size} components but the scene is {dim}D"
            )
    else:
        vel = np.zeros(dim)

    regions = entity.fixed_regions
    try:
        fixed = points_in_regions(regions, x)
    except ValueError as exc:
        raise ValueError(f"entity '{entity.name}': fixed region: {exc}") from None
    for j, region in enumerate(regions):
        if n and not np.any(points_in_shape(region, x)):
            where = f" #{j}" if len(regions) > 1 else ""
            warnings.append(f"fixed region{where} ({region.type}) holds no particle of this entity")

    kwargs = {
        "name": entity.name,
        "entity": entity,
        "x": x,
        "v": np.broadcast_to(vel, (n, dim)) + velocity_field(entity, x),
        "volume": np.full(n, per_volume),
        "mass": np.full(n, rho * per_volume),
        "fixed": fixed,
    }
    body = Body(**kwargs, warnings=list(warnings))
    for w in warnings:
        log.debug("%s: %s", entity.name, w)  # the runner reports body.warnings itself
    return body


# Families whose entities are sampled as particles, and where each takes its particle spacing from.
PARTICLE_FAMILIES = ("MPM", "SPH")


def family_spacing(scene, family: str) -> float:
    """Particle spacing [m] of a family: solvers.sph.particle_size for SPH, solvers.mpm.spacing for MPM."""
    if family == "SPH":
        return float(scene.solvers.sph.particle_size)
    return float(scene.solvers.mpm.spacing)


def entity_rng(seed: int, index: int) -> np.random.Generator:
    """The random generator of the index-th entity: independent of the other entities."""
    return np.random.default_rng(np.random.SeedSequence([int(seed) % 2**63, int(index)]))


def sample_scene(scene, scene_dir: PathLike | None = None, seed: int | None = None) -> list[Body]:
    """Bodies of every particle entity (MPM, SPH), in entity order (each entity jittered by its own
    generator)."""
    if seed is None:
        seed = scene.sim.seed
    scene_dir = Path(scene_dir) if scene_dir is not None else None
    return [
        sample_entity(e, scene, scene_dir, entity_rng(seed, i))
        for i, e in enumerate(scene.entities)
        if e.family in PARTICLE_FAMILIES
    ]


def _thin_layer(points: np.ndarray, h: float) -> np.ndarray:
    """One particle per h/2 cell among the thin-part midpoints (rays along different axes find the
    same thin part)."""
    if not len(points):
        return points
    key = np.floor(points / (0.5 * h)).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return points[np.sort(first)]


# ------------------------------------------------------------------ Poisson-disk sampling

POISSON_RADIUS = {2: 0.80, 3: 0.87}  # minimum distance / spacing: about V / h^d points after the trials
POISSON_TRIALS = 12  # dart-throwing passes (one candidate per empty cell and phase each)
POISSON_MARGIN = 0.15  # distance of the points from an analytic shape's faces / spacing


def poisson_disk(lo, hi, radius: float, rng, trials: int = POISSON_TRIALS, inside=None) -> np.ndarray:
    """Points in the box [lo, hi] no two closer than ``radius`` (see the module docstring).

    ``inside``: optional function (origin, spacing, shape) -> bool array of that shape telling which
    background cell centres origin + spacing * index lie inside the shape; cells farther than one
    cell from the shape get no candidates (a curved shape's bounding box is mostly empty: this
    skips the work there)."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    dim = lo.size
    r = float(radius)
    a = r / np.sqrt(dim)  # a cell's diagonal is r: at most one point per cell
    shape = np.maximum(1, np.ceil((hi - lo) / a - 1e-9)).astype(np.int64)
    reach = int(np.ceil(np.sqrt(dim)))  # cells that can hold a point closer than r
    # point index per cell, padded by `reach` empty cells on every side (no bounds checks)
    owner = np.full(shape + 2 * reach, -1, dtype=np.int64)
    pts = np.zeros((0, dim))
    offs = np.stack(np.meshgrid(*[np.arange(-reach, reach + 1)] * dim, indexing="ij"), -1).reshape(-1, dim)
    gap = np.maximum(np.abs(offs) - 1, 0)
    offs = offs[(gap**2).sum(axis=1) < dim]  # the cell blocks' closest points are nearer than r
    period = reach + 1  # cells `period` apart are at least (period - 1) a >= r apart: no conflict
    weights = period ** np.arange(dim)
    all_cells = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).reshape(-1, dim)
    if inside is not None:  # only cells within one cell of the shape
        hit = np.asarray(inside(lo + 0.5 * a, a, tuple(int(n) for n in shape)), dtype=bool)
        grown = hit.copy()
        for ax in range(dim):
            grown |= np.roll(hit, 1, axis=ax) | np.roll(hit, -1, axis=ax)
        all_cells = all_cells[grown.reshape(-1)]
    phase_of = (all_cells % period) @ weights
    by_phase = [all_cells[phase_of == k] + reach for k in range(period**dim)]
    strides = np.array([int(np.prod(owner.shape[k + 1 :])) for k in range(dim)], dtype=np.int64)
    flat_offs = offs @ strides
    flat_owner = owner.reshape(-1)  # a view: writes go to owner
    r2 = r * r
    for _ in range(trials):
        for cells in by_phase:
            flat = cells @ strides
            empty = flat_owner[flat] < 0
            cells, flat = cells[empty], flat[empty]
            if not len(cells):
                continue
            cand = lo + (cells - reach + rng.random(cells.shape)) * a
            nb = flat_owner[flat[:, None] + flat_offs[None, :]]  # (cells, offsets): neighbours' points
            rows, cols = np.nonzero(nb >= 0)
            d2 = ((cand[rows] - pts[nb[rows, cols]]) ** 2).sum(axis=1)
            ok = np.all(cand <= hi, axis=1)
            ok[rows[d2 < r2]] = False
            new = cand[ok]
            flat_owner[flat[ok]] = len(pts) + np.arange(len(new))
            pts = np.concatenate([pts, new])
    return pts


def _poisson_fill(morph, h: float, dim: int, scene_dir, rng) -> tuple[np.ndarray, float]:
    """Poisson-disk points inside the morph (POISSON_MARGIN h from an analytic shape's faces) and its
    volume."""
    r = POISSON_RADIUS[dim] * h
    m = POISSON_MARGIN * h
    if isinstance(morph, MeshShape):
        mesh = load_mesh_morph(morph, scene_dir)
        lo, hi = mesh.bounds
        x = poisson_disk(
            lo,
            hi,
            r,
            rng,
            inside=lambda o, a, n: lattice_inside_mesh(mesh, o, a, n, thin_check_axes=()).inside,
        )
        return x[points_inside_mesh(mesh, x, bin_size=h)], float(mesh.volume)
    volume = shape_volume(morph, dim)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in morph.bounds())
    if isinstance(morph, BoxShape):
        m = np.minimum(m, 0.25 * (hi - lo))  # a box thinner than r still gets a layer
        return poisson_disk(lo + m, hi - m, r, rng), volume
    if isinstance(morph, SphereShape):
        inner = morph.model_copy(update={"radius": max(morph.radius - m, 0.5 * morph.radius)})
    else:  # Cylinder
        inner = morph.model_copy(
            update={
                "radius": max(morph.radius - m, 0.5 * morph.radius),
                "height": max(morph.height - 2 * m, 0.5 * morph.height),
            }
        )
    x = poisson_disk(
        lo,
        hi,
        r,
        rng,
        inside=lambda o, a, n: points_in_shape(
            inner, _lattice_points(np.asarray(o), np.asarray(n), a)
        ).reshape(n),
    )
    return x[points_in_shape(inner, x)], volume
