"""Semantic checks that need the whole scene: dimensions, duplicate names, entities inside
the domain, mesh files, and a memory estimate made before anything is allocated."""

from __future__ import annotations

import math
from pathlib import Path

from simcli.scene.loader import LoadedScene, sort_lines

# Bytes of solver state per MPM particle and per grid node, f32 (f64 doubles them).
# Particle: x, v (dim each), C, F (dim^2 each), volume, mass, material id, fixed flag,
# warm-start rotation (4), Jp; plus one host copy for output.
_BYTES_PER_PARTICLE_3D = 4 * (3 + 3 + 9 + 9 + 4 + 6) + 4 * 12
_BYTES_PER_PARTICLE_2D = 4 * (2 + 2 + 4 + 4 + 2 + 6) + 4 * 8
_BYTES_PER_CELL = {2: 4 * 3, 3: 4 * 4}  # grid momentum/velocity (dim) + mass
# SPH, f32: per particle x, v, new v, boundary gradient sum (dim each), 10 scalars, 6 ints, the reorder
# copies (2 dim + 4) and the neighbour list (capacity x (index + gradient)); per boundary particle
# position, velocity, volume, flag; per cell (cell = support / 2) count and start offsets of the liquid
# and of the boundary particles.
_SPH_CAPACITY = {2: 32, 3: 64}
_SPH_BYTES_PER_PARTICLE = {d: 4 * (4 * d + 10 + 6 + 2 * d + 4 + _SPH_CAPACITY[d] * (1 + d)) for d in (2, 3)}
_SPH_BYTES_PER_BOUNDARY = {d: 4 * (2 * d + 2) for d in (2, 3)}
_SPH_BYTES_PER_CELL = 4 * 3
MEMORY_FRACTION = 0.8  # refuse a scene that needs more than this share of available memory


def _available_memory() -> int:
    try:
        import psutil

        return int(psutil.virtual_memory().available)
    except Exception:  # pragma: no cover - psutil missing
        try:
            with open("/proc/meminfo") as f:
                for line in f:
                    if line.startswith("MemAvailable:"):
                        return int(line.split()[1]) * 1024
        except OSError:
            pass
    return 1 << 62


def check_scene(loaded: LoadedScene) -> list[str]:
    s = loaded.scene
    loc = loaded.located
    dim = s.sim.dim
    errors: list[str] = []

    def err(path: tuple, msg: str, key: bool = False):
        dotted = ".".join(str(p) for p in path)
        errors.append(f"{loc.where(path, prefer_key=key)}: {dotted}: {msg}")

    def need_len(path: tuple, vec, what: str = "components"):
        if vec is not None and len(vec) != dim:
            err(path, f"expected {dim} {what} for dim {dim} (got {len(vec)})")
            return False
        return True

    # domain
    lo, hi = s.domain.bounds(dim)
    ok_dom = need_len(("domain", "lower"), s.domain.lower) & need_len(("domain", "upper"), s.domain.upper)
    if ok_dom:
        for a, (x0, x1) in enumerate(zip(lo, hi)):
            if not x0 < x1:
                err(("domain", "upper"), f"lower must be < upper on every axis (axis {'xyz'[a]}: {x0} >= {x1})")
                ok_dom = False
    for face, b in s.domain.faces.items():
        if dim == 2 and face[0] == "z":
            err(("domain", "faces", face), "z faces exist only in 3D (dim 2 has x-, x+, y-, y+)", key=True)
        need_len(("domain", "faces", face, "velocity"), b.velocity)
    need_len(("domain", "boundary", "velocity"), s.domain.boundary.velocity)

    # colliders
    for i, c in enumerate(s.colliders):
        base = ("colliders", i)
        for f in ("point", "normal", "lower", "upper", "center"):
            need_len(base + (f,), getattr(c, f, None))
        if c.type == "Cylinder" and dim == 2:
            err(base + ("type",), "Cylinder colliders need dim 3 (use a Box in 2D)")
        if c.type == "Plane" and all(abs(x) == 0 for x in c.normal):
            err(base + ("normal",), "normal must not be zero")
        if c.type == "Box" and len(c.lower) == len(c.upper) and any(a >= b for a, b in zip(c.lower, c.upper)):
            err(base + ("upper",), f"lower must be < upper on every axis (got lower {c.lower}, upper {c.upper})")

    # entities
    seen: dict[str, int] = {}
    n_particles = 0
    n_sph = 0
    mpm = s.solvers.mpm
    sph = s.solvers.sph
    for i, e in enumerate(s.entities):
        base = ("entities", i)
        if e.name in seen:
            err(base + ("name",), f"duplicate entity name '{e.name}' (also entities.{seen[e.name]}.name); "
                "names must be unique")
        else:
            seen[e.name] = i
        need_len(base + ("velocity",), e.velocity)
        m = e.morph
        mpath = base + ("morph",)
        shape_ok = True
        for f in ("lower", "upper", "center", "size"):
            shape_ok &= need_len(mpath + (f,), getattr(m, f, None))
        if dim == 2 and m.type in ("Cylinder", "Mesh"):
            err(mpath + ("type",), f"{m.type} morphs need dim 3 (use a Box or Sphere in 2D)")
            shape_ok = False
        if m.type == "Mesh" and shape_ok:
            f = (loaded.scene_dir / m.file) if not Path(m.file).is_absolute() else Path(m.file)
            if not f.exists():
                err(mpath + ("file",), f"mesh file not found: {f} (paths are relative to the scene file)")
                shape_ok = False
        for j, r in enumerate(e.fixed_regions):
            rpath = base + ("fixed",) + ((j,) if isinstance(e.fixed, list) else ())
            for f in ("lower", "upper", "center", "size"):
                need_len(rpath + (f,), getattr(r, f, None))
            if dim == 2 and r.type == "Cylinder":
                err(rpath + ("type",), "Cylinder regions need dim 3 (use a Box or Sphere in 2D)")
        if not (shape_ok and ok_dom):
            continue
        try:
            from simcli.geometry.sampling import estimate_particle_count, morph_bounds

            mlo, mhi = morph_bounds(m, loaded.scene_dir)
            if e.family == "MPM":
                n_particles += estimate_particle_count(m, mpm.spacing, dim, loaded.scene_dir)
            elif e.family == "SPH":
                n_sph += estimate_particle_count(m, sph.particle_size, dim, loaded.scene_dir)
        except Exception as ex:  # mesh unreadable or not closed
            err(mpath + ("file",) if m.type == "Mesh" else mpath, str(ex))
            continue
        tol = 1e-9
        outside = [a for a in range(dim) if mlo[a] < lo[a] - tol or mhi[a] > hi[a] + tol]
        if outside:
            axes = ", ".join("xyz"[a] for a in outside)
            err(mpath, f"entity '{e.name}' extends outside the domain along {axes} (its bounds "
                f"{_fmt(mlo)}..{_fmt(mhi)}, domain {_fmt(lo)}..{_fmt(hi)}); move it or enlarge domain")

    if errors:
        return sort_lines(errors)

    # memory estimate, before anything is allocated
    fp = 2 if s.sim.precision == "f64" else 1
    per_p = (_BYTES_PER_PARTICLE_3D if dim == 3 else _BYTES_PER_PARTICLE_2D) * fp
    cells = 1
    if "MPM" in s.families:
        for a in range(dim):
            cells *= int(math.ceil((hi[a] - lo[a]) * mpm.grid_density)) + 7
    need = n_particles * per_p + cells * _BYTES_PER_CELL[dim] * fp
    if "SPH" in s.families:
        # boundary particles: two layers outside every face of the domain (colliders add less)
        ext = [hi[a] - lo[a] for a in range(dim)]
        faces = sum(math.prod(ext[b] for b in range(dim) if b != a) for a in range(dim))
        n_bnd = int(2 * 2 * faces / sph.particle_size ** (dim - 1))
        sph_cells = math.prod(int(math.ceil(e / sph.particle_size)) + 6 for e in ext)
        need += (n_sph * _SPH_BYTES_PER_PARTICLE[dim] + n_bnd * _SPH_BYTES_PER_BOUNDARY[dim]
                 + sph_cells * _SPH_BYTES_PER_CELL) * fp
        n_particles += n_sph
    avail = _available_memory()
    if need > MEMORY_FRACTION * avail:
        err(("solvers", "mpm", "grid_density") if "MPM" in s.families
            else ("solvers", "sph", "particle_size") if "SPH" in s.families else ("entities",),
            f"scene too large: needs about {need / 2**30:.1f} GiB ({n_particles:,} particles, {cells:,} grid "
            f"nodes) but only {avail / 2**30:.1f} GiB is available; lower solvers.mpm.grid_density, raise "
            f"particle_size or shrink the domain")
    return errors


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"
