"""Bounds on what a scene may ask for, checked before anything is allocated (docs/LIMITS.md).

Three kinds, each reported as ``file:line:col: key: message`` with the key to change:

- values that no material has or the machine cannot do: material parameters outside plausible physical
  ranges, more than ``MAX_TOTAL_SUBSTEPS`` substeps, names that are not safe as HDF5 groups and file names;
- a fixed substep far over the stability limit of the scene at rest (a Taichi-free estimate of what the
  solvers' ``stable_dt`` reports at frame 0), with the likely unit slip named;
- geometry at the start: entities of one solver family overlapping, an entity entirely inside a collider.

``check_limits`` returns errors (exit 65); ``scene_warnings`` returns lines that ``validate`` and ``run``
print and that do not stop a run (a partial overlap with a collider, threads clamped to the cores).
No Taichi here.
"""

from __future__ import annotations

import math
import os
import re

import numpy as np

from simcli.scene.coupling import coupled, coupling_warnings, mpm_sph_by_particles, sph_fem_by_particles

# the families whose bodies SPH meets as boundary particles, and the rule that says when
SPH_SAMPLED = {"FEM": sph_fem_by_particles, "MPM": mpm_sph_by_particles}

# ------------------------------------------------------------------ bounds

# A run of more substeps than this is refused: at a (fast) 1e-6 s per substep of a tiny scene it is
# already 20 minutes of pure stepping; a scene that needs more is a unit slip in sim.dt or sim.duration.
MAX_TOTAL_SUBSTEPS = 10**9
# Steps of a run (substeps: auto picks the substeps per step, up to the runner's AUTO_MAX_SUBSTEPS).
MAX_STEPS = 10**9

# Plausible physical ranges [lower, upper] of material parameters, by field name, in SI units. The
# ranges span every real material with a wide margin (E: aerogel ~1e4 Pa .. diamond 1.2e12 Pa;
# rho: aerogel 1 kg/m^3, air 1.2 .. osmium 22,590 kg/m^3; PBD cloth rho is an areal density kg/m^2;
# viscosity: 0 .. pitch ~2e8 Pa s); a value outside is a unit slip or a typo, and it overflows f32
# kernels (E 1e300 reached the solver and overflowed).
MATERIAL_RANGES: dict[str, tuple[float, float, str]] = {
    "E": (1.0, 1.0e13, "Pa"),
    "rho": (1.0e-3, 1.0e5, "kg/m^3"),
    "stiffness": (0.0, 1.0e13, "Pa"),  # SPH.Liquid's Tait stiffness, muscle stiffness
    "mu": (0.0, 1.0e12, "Pa s"),  # dynamic viscosity (MPM.Liquid, SPH.Liquid)
    "viscosity": (0.0, 1.0e6, "m^2/s"),  # SF.Smoke kinematic viscosity
    "cohesion": (0.0, 1.0e13, "Pa"),
    "von_mises_yield_stress": (0.0, 1.0e13, "Pa"),
}

# Largest coordinate magnitude of any position [m]: beyond it f32 positions lose millimetres and grid sizes
# overflow integer indices.
MAX_COORD = 1.0e6

# A fixed substep is refused when it exceeds the stability limit estimated at rest by more than this factor
# (the solvers' limits carry a safety factor of about 0.5: twice the limit is past the true CFL bound, and
# the state only gets faster than at rest). Between 1x and this factor the run warns, as before.
REFUSE_FACTOR = 2.0

# Entity and scene names: used as HDF5 group names, file names (name.vtu, name_000.vtu) and output folders.
NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_+=.-]{0,127}$")
NAME_RULE = (
    "use letters, digits, '_', '-', '+', '=' and '.', at most 128 characters, not starting with '.' or '-' "
    "and without '..' (it names HDF5 groups and files in the output folder)"
)

# Overlap between two entities of one family: refused above this share of the smaller one's volume.
OVERLAP_FRACTION = 0.01


def name_problem(name: str) -> str | None:
    """Why ``name`` is not safe as an HDF5 group / file name, or None."""
    if not NAME_RE.match(name) or ".." in name:
        return f"name {name!r} is not allowed: {NAME_RULE}"
    return None


def allowed_threads() -> int:
    """CPU cores this process may run on (its affinity mask: a Slurm allocation, taskset, a cgroup)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


# ------------------------------------------------------------------ errors


def check_limits(loaded, geometry_ok: bool = True) -> list[str]:
    """Every bound of this module that the scene breaks, one formatted line each. ``geometry_ok``: the
    scene's shapes passed their own checks (dimensions, inside the domain), so overlaps can be measured."""
    s = loaded.scene
    loc = loaded.located
    out: list[str] = []

    def err(path: tuple, msg: str, key: bool = False):
        dotted = ".".join(str(p) for p in path) or "(top level)"
        out.append(f"{loc.where(path, prefer_key=key)}: {dotted}: {msg}")

    if not s.entities and not getattr(s, "emitters", None):
        err(
            ("entities",) if "entities" in loc.data else (),
            "the scene has no entities: add at least one under entities: (a name, a material and a morph)",
            key=True,
        )
    if s.name is not None and (p := name_problem(s.name)):
        err(("name",), p)
    for i, e in enumerate(s.entities):
        if p := name_problem(e.name):
            err(("entities", i, "name"), p)
        for key, (lo, hi, unit) in MATERIAL_RANGES.items():
            if key not in type(e.material).model_fields:
                continue
            v = getattr(e.material, key)
            if isinstance(v, (int, float)) and not lo <= v <= hi:
                err(
                    ("entities", i, "material", key),
                    f"{v:g} {unit} is outside the plausible range {lo:g}..{hi:g} {unit} of any material "
                    f"(SI units: {_unit_hint(key)})",
                )
    if not out and geometry_ok:
        out += check_overlaps(loaded)[0]
    return out


# Solver resolutions: beyond these the sizes and counts derived from them overflow (a particle_size of 1e-300
# squared is 0) long before the memory estimate could say "too large"; every real scene is far inside.
OPTION_RANGES: dict[tuple[str, str], tuple[float, float, str]] = {
    ("mpm", "grid_density"): (1.0e-3, 1.0e6, "cells/m"),
    ("mpm", "particle_size"): (1.0e-6, 1.0e3, "m"),
    ("sph", "particle_size"): (1.0e-6, 1.0e3, "m"),
    ("sph", "support_factor"): (1.0, 10.0, "particle sizes"),
    ("pbd", "particle_size"): (1.0e-6, 1.0e3, "m"),
    ("pbd", "tet_resolution"): (1.0e-3, 1.0e6, "cells/m"),
    ("fem", "resolution"): (1.0e-3, 1.0e6, "cells/m"),
    ("fem", "surface_resolution"): (1.0e-3, 1.0e6, "cells/m"),
    ("fem", "max_volume"): (1.0e-18, 1.0e9, "m^3"),
}
MAX_ITERATIONS = 10**6  # any solver iteration cap (pcg_max_iter, max_iterations, ...)


def check_bounds(loaded) -> list[str]:
    """Bounds that keep the semantic checks' own arithmetic finite (coordinates, step counts, solver
    resolutions): run before ``check_scene``, whose estimates would otherwise overflow or divide by zero."""
    s = loaded.scene
    loc = loaded.located
    out: list[str] = []

    def err(path: tuple, msg: str, key: bool = False):
        dotted = ".".join(str(p) for p in path) or "(top level)"
        out.append(f"{loc.where(path, prefer_key=key)}: {dotted}: {msg}")

    for (fam, key), (lo, hi, unit) in OPTION_RANGES.items():
        v = getattr(getattr(s.solvers, fam), key, None)
        if isinstance(v, (int, float)) and not lo <= v <= hi:
            err(
                ("solvers", fam, key),
                f"{v:g} {unit} is outside the range {lo:g}..{hi:g} {unit} a solver can use",
            )
    for fam in type(s.solvers).model_fields:
        opts = getattr(s.solvers, fam)
        for key in type(opts).model_fields:
            v = getattr(opts, key)
            if (
                ("iter" in key or key in ("check_every", "smoothing"))
                and isinstance(v, int)
                and v > MAX_ITERATIONS
            ):
                err(
                    ("solvers", fam, key),
                    f"{v} is more than the {MAX_ITERATIONS:,} iterations any solve needs",
                )
    _check_coords(loc.data, (), err)
    _check_time(s, err)
    return out


def _unit_hint(key: str) -> str:
    return {
        "E": "Pa, e.g. rubber 1e6, steel 2e11",
        "rho": "kg/m^3, e.g. water 1000",
        "mu": "Pa s, e.g. water 1e-3, honey 10",
        "stiffness": "Pa",
        "viscosity": "m^2/s, e.g. air 1.5e-5",
    }.get(key, "Pa")


_COORD_KEYS = {"lower", "upper", "center", "point", "size", "gravity", "velocity", "radius", "height"}


def _check_coords(data, path: tuple, err) -> None:
    """Positions, sizes, velocities and gravity bounded by MAX_COORD (their arithmetic must not overflow)."""
    if isinstance(data, dict):
        for k, v in data.items():
            _check_coords(v, path + (k,), err)
    elif isinstance(data, list):
        for i, v in enumerate(data):
            _check_coords(v, path + (i,), err)
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        names = [p for p in path if isinstance(p, str)]
        if names and names[-1] in _COORD_KEYS and abs(data) > MAX_COORD:
            err(path, f"{data:g} is beyond the {MAX_COORD:g} (m, m/s, m/s^2) any scene needs; check its unit")


def _check_time(s, err) -> None:
    sim = s.sim
    if sim.steps is not None:
        n_steps = float(sim.steps)
        where = ("sim", "steps")
    else:
        n_steps = (1.0 if sim.duration is None else sim.duration) / sim.dt
        # point at the odd one: a step under 10 ns is a unit slip in dt, otherwise the duration is long
        where = ("sim", "duration") if sim.duration is not None and sim.dt >= 1e-8 else ("sim", "dt")
    if not math.isfinite(n_steps) or n_steps > MAX_STEPS:
        err(
            where,
            f"{n_steps:.3g} steps (sim.duration / sim.dt) exceed the {MAX_STEPS:.0e} a run may take; check "
            "the units of sim.dt and sim.duration (seconds)",
        )
        return
    if isinstance(sim.substeps, int) and n_steps * sim.substeps > MAX_TOTAL_SUBSTEPS:
        err(
            ("sim", "substeps") if sim.steps is None and sim.duration is None else where,
            f"{n_steps * sim.substeps:.3g} substeps (steps x sim.substeps) exceed the "
            f"{MAX_TOTAL_SUBSTEPS:.0e} "
            "a run may take; shorten sim.duration (or sim.steps), raise sim.dt or lower sim.substeps",
        )


# ------------------------------------------------------------------ stability


def stability_estimates(scene) -> list[tuple[float, int, str, str]]:
    """Taichi-free estimates of each family's stability limit at rest (what its ``stable_dt`` reports at frame
    0 for a scene at rest, speeds left out: they only lower it): a list of (limit [s], entity index, what
    limits it, the limit's formula in words). PBD and SF are unconditionally stable (no entry)."""
    out = []
    dim = scene.sim.dim
    mpm = scene.solvers.mpm
    sph = scene.solvers.sph
    fem = scene.solvers.fem
    for i, e in enumerate(scene.entities):
        m = e.material
        fam = e.family
        if fam == "MPM":
            dx = mpm.dx
            nu = float(m.nu)
            E = float(m.E)
            lam = E * nu / ((1 + nu) * (1 - 2 * nu))
            mu = 0.0 if m.type == "MPM.Liquid" else E / (2 * (1 + nu))
            c = math.sqrt((lam + 2 * mu) / float(m.rho))
            if c > 0:
                out.append((0.5 * dx / c, i, "wave", f"0.5 dx / c_p, dx {dx:.3g} m, c_p {c:.3g} m/s"))
            if getattr(m, "viscous", False) and m.mu > 0:
                lim = 0.5 * float(m.rho) * dx**2 / (2.0 * dim * m.mu)
                out.append((lim, i, "viscosity", f"rho dx^2 / (4 dim mu), dx {dx:.3g} m"))
        elif fam == "SPH":
            ps = sph.particle_size
            if sph.pressure_solver == "WCSPH":
                c = math.sqrt(m.stiffness * m.exponent / m.rho)
                if c > 0:
                    out.append(
                        (sph.cfl * ps / c, i, "wave", f"cfl ps / c, ps {ps:.3g} m, sound speed {c:.3g} m/s")
                    )
            if m.mu > 0:
                out.append(
                    (0.05 * ps**2 * m.rho / m.mu, i, "viscosity", f"0.05 ps^2 rho / mu, ps {ps:.3g} m")
                )
        elif fam == "FEM" and fem.integrator == "explicit":
            E, nu = float(m.E), float(m.nu)
            c = math.sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu)) / float(m.rho))
            h = 1.0 / fem.resolution  # the Box cell: larger than any element height, so the limit is generous
            if e.morph is not None and e.morph.type == "Box" and c > 0:
                out.append(
                    (fem.cfl * h / c, i, "wave", f"cfl h / c_p, h <= {h:.3g} m, c_p {c:.3g} m/s (explicit)")
                )
    return out


def check_stability(loaded) -> list[str]:
    """A fixed substep more than REFUSE_FACTOR times over a family's stability limit at rest: one line, with
    the likely unit slip and the key to change (``check_scene`` calls it last, after the memory estimate)."""
    out: list[str] = []

    def err(path: tuple, msg: str):
        out.append(f"{loaded.located.where(path)}: {'.'.join(str(p) for p in path)}: {msg}")

    _check_stability(loaded, err)
    return out


def _check_stability(loaded, err) -> None:
    s = loaded.scene
    if s.sim.substeps == "auto":
        return
    sub = s.sim.dt / s.sim.substeps
    for lim, i, what, formula in stability_estimates(s):
        if not (lim > 0 and sub > REFUSE_FACTOR * lim):
            continue
        e = s.entities[i]
        m = e.material
        need = math.ceil(s.sim.dt / lim)
        slip, path = _unit_slip(s, e, i, what)
        err(
            path,
            f"the fixed substep sim.dt / sim.substeps = {sub:.3g} s is {sub / lim:.0f}x the stability limit "
            f"{lim:.3g} s of entities.{i} '{e.name}' ({m.type}, {what}: {formula}); it would blow up. "
            f"{slip}Otherwise set sim.substeps >= {need}, sim.substeps: auto, or a smaller sim.dt",
        )
        return  # one line: the worst offender's advice is enough


def _unit_slip(s, e, i: int, what: str) -> tuple[str, tuple]:
    """The likely unit slip behind an unstable substep, and the key to change."""
    m = e.material
    base = ("entities", i, "material")
    rho = getattr(m, "rho", None)
    if rho is not None and rho < 50 and e.family in ("MPM", "SPH", "FEM"):
        return (
            f"rho: {rho:g} looks like g/cm^3 or a relative density: rho is in kg/m^3 (water 1000); fix "
            f"entities.{i}.material.rho. ",
            base + ("rho",),
        )
    E = getattr(m, "E", None)
    if what == "wave" and E is not None and E >= 1e10 and e.family != "MPM":
        return (
            f"E: {E:g} Pa is steel-like; if it was meant in kPa or MPa, fix entities.{i}.material.E. ",
            base + ("E",),
        )
    if what == "wave" and E is not None and E >= 1e9:
        return (
            f"E: {E:g} Pa is stiff (steel 2e11); if it was meant in kPa or MPa, fix "
            f"entities.{i}.material.E. ",
            base + ("E",),
        )
    if s.sim.dt >= 0.05:
        return (
            f"sim.dt: {s.sim.dt:g} s is long for a step (typical 1e-3..1e-2 s); sim.dt is in seconds, not "
            "milliseconds. ",
            ("sim", "dt"),
        )
    return "", ("sim", "substeps")


# ------------------------------------------------------------------ geometry at the start


def _analytic(morph) -> bool:
    return morph is not None and morph.type in ("Box", "Sphere", "Cylinder")


def _lattice(lo, hi, n: int) -> np.ndarray:
    """Cell centres of an n^dim lattice over [lo, hi]."""
    axes = [lo[a] + (np.arange(n) + 0.5) * (hi[a] - lo[a]) / n for a in range(len(lo))]
    return np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)


def _collider_inside(c, x: np.ndarray, s=None, scene_dir=None) -> np.ndarray:
    """Points strictly inside a collider (numpy, the same shapes as simcli.colliders)."""
    if c.type == "Mesh":  # its signed-distance grid, as the solvers see it
        from simcli.collider_mesh import inside_mesh_collider

        return inside_mesh_collider(c, x, s, scene_dir)
    if c.type == "Plane":
        n = np.asarray(c.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        return (x - np.asarray(c.point)) @ n < 0
    if c.type == "Box":
        return np.all((x > np.asarray(c.lower)) & (x < np.asarray(c.upper)), axis=1)
    if c.type == "Sphere":
        return np.sum((x - np.asarray(c.center)) ** 2, axis=1) < c.radius**2
    ax = "xyz".index(c.axis)
    d = x - np.asarray(c.center)
    return (np.abs(d[:, ax]) < c.height / 2) & (np.sum(d**2, axis=1) - d[:, ax] ** 2 < c.radius**2)


def _overlaps(s, scene_dir=None) -> tuple[list, list]:
    """(entity pairs, entity-collider pairs) overlapping at the start: (i, j_or_collider, volume,
    share of i)."""
    from simcli.geometry.regions import points_in_shape, shape_volume

    dim = s.sim.dim
    pairs, inside = [], []
    ents = [(i, e) for i, e in enumerate(s.entities) if _analytic(e.morph) and e.family != "SF"]
    n = 24 if dim == 3 else 96
    for k, (i, a) in enumerate(ents):
        va = shape_volume(a.morph, dim)
        alo, ahi = (np.asarray(b, dtype=np.float64) for b in _shape_bounds(a.morph, dim))
        for j, b in ents[k + 1 :]:
            blo, bhi = (np.asarray(v, dtype=np.float64) for v in _shape_bounds(b.morph, dim))
            lo, hi = np.maximum(alo, blo), np.minimum(ahi, bhi)
            if np.any(hi <= lo):
                continue
            x = _lattice(lo, hi, n)
            both = points_in_shape(a.morph, x) & points_in_shape(b.morph, x)
            vol = float(both.mean() * np.prod(hi - lo))
            vb = shape_volume(b.morph, dim)
            if vol > 0:
                pairs.append((i, j, vol, vol / min(va, vb)))
        x = _lattice(alo, ahi, n)
        x = x[points_in_shape(a.morph, x)]
        if not len(x):
            continue
        for ci, c in enumerate(s.colliders):
            frac = float(_collider_inside(c, x, s, scene_dir).mean())
            if frac > 0:
                inside.append((i, ci, frac * va, frac))
    return pairs, inside


def _shape_bounds(morph, dim: int):
    lo, hi = morph.bounds()
    return lo[:dim], hi[:dim]


def check_overlaps(loaded) -> tuple[list[str], list[str]]:
    """(errors, warnings) for overlaps at the start. Two entities of one particle family overlapping by more
    than OVERLAP_FRACTION of the smaller: an error (their particles sit on top of each other: twice the mass
    and a violent push-out). Entities of different families: a warning with the volume (coupling is through
    colliders only, so they pass through each other; legitimate, e.g. a PBD cloth draped through a smoke
    source). An entity entirely inside a collider: an error (it is smeared over the surface); partly inside:
    a warning with the volume (pushed out in the first substeps; the hard cases test it)."""
    s = loaded.scene
    loc = loaded.located
    errors, warns = [], []
    try:
        pairs, inside = _overlaps(s, getattr(loaded, "scene_dir", None))
    except (ValueError, FloatingPointError):  # a shape the estimate cannot handle: no verdict
        return errors, warns
    unit = "m^3" if s.sim.dim == 3 else "m^2"
    for i, j, vol, share in pairs:
        a, b = s.entities[i], s.entities[j]
        head = f"{loc.where(('entities', j, 'morph'))}: entities.{j}.morph: "
        text = (
            f"entity '{b.name}' overlaps entity '{a.name}' (entities.{i}) at the start by about "
            f"{vol:.3g} {unit} "
            f"({100 * share:.0f}% of the smaller)"
        )
        if a.family == b.family and share > OVERLAP_FRACTION:
            errors.append(f"{head}{text}; their particles would sit on top of each other: move one")
        elif a.family != b.family:
            body = b.family if a.family == "SPH" else a.family if b.family == "SPH" else None
            if body in SPH_SAMPLED and SPH_SAMPLED[body](s):
                warns.append(  # the body is SPH boundary particles (simcli/coupling/sph_fem.py, mpm_sph.py)
                    f"{head}warning: {text}; the liquid's particles inside the {body} body are removed at "
                    "the start"
                )
            elif coupled(s, a.family, b.family):
                # coupled families push each other apart in the first substeps
                warns.append(
                    f"{head}warning: {text}; {a.family} and {b.family} push each other out at the start"
                )
            else:
                warns.append(f"{head}warning: {text}; {a.family} and {b.family} do not interact")
    for i, ci, vol, frac in inside:
        e = s.entities[i]
        head = f"{loc.where(('entities', i, 'morph'))}: entities.{i}.morph: "
        c = s.colliders[ci]
        if frac >= 0.999:
            errors.append(
                f"{head}entity '{e.name}' is entirely inside colliders.{ci} ({c.type}); it would be "
                "smeared over "
                "the collider's surface: move it or the collider"
            )
        else:
            warns.append(
                f"{head}warning: entity '{e.name}' is {100 * frac:.0f}% inside colliders.{ci} "
                f"({c.type}), about "
                f"{vol:.3g} {unit}; that part is pushed out at the start"
            )
    return errors, warns


# ------------------------------------------------------------------ warnings


def scene_warnings(loaded) -> list[str]:
    """Lines that do not stop a run: partial overlaps, sim.threads clamped to the cores this process
    may use."""
    s = loaded.scene
    loc = loaded.located
    out: list[str] = []
    cores = allowed_threads()
    if s.sim.threads is not None and s.sim.threads > cores:
        out.append(
            f"{loc.where(('sim', 'threads'))}: sim.threads: warning: {s.sim.threads} threads asked, "
            "this process "
            f"may use {cores} cores; running with {cores} (more threads than cores only slow a run down)"
        )
    out += check_overlaps(loaded)[1]
    out += coupling_warnings(loaded)  # coupling keys of pairs not in the scene
    if s.sim.dim == 2 and any(e.material.type == "PBD.Liquid" for e in s.entities):
        for i, rb in enumerate(getattr(s, "rigid_bodies", None) or []):
            if rb.morph.type == "Sphere":
                out.append(
                    f"{loc.where(('rigid_bodies', i, 'morph', 'type'))}: rigid_bodies.{i}: warning: a 2D "
                    "Sphere (disk) body counts in PBD.Liquid's density as the half-plane behind its "
                    "tangent, which over-counts a disk a few particles across (its buoyancy is too large; "
                    "docs/PBD.md, Gaps); only Box bodies are validated in 2D PBF"
                )
    return out
