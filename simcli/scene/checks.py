"""Semantic checks that need the whole scene: dimensions, duplicate names, entities inside
the domain, mesh files, and a memory estimate made before anything is allocated."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from simcli.scene.lines import sort_lines


def check_scene(loaded: Any) -> list[str]:  # a simcli.scene.loader.LoadedScene (the loader calls this)
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
                err(
                    ("domain", "upper"),
                    f"lower must be < upper on every axis (axis {'xyz'[a]}: {x0} >= {x1})",
                )
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
            err(
                base + ("upper",),
                f"lower must be < upper on every axis (got lower {c.lower}, upper {c.upper})",
            )
        if getattr(c, "cpic", False):  # CPIC (docs/MPM.md): an MPM feature of the APIC transfer
            if not any(str(e.material.type).startswith("MPM.") for e in s.entities):
                err(
                    base + ("cpic",),
                    "cpic: true acts on MPM materials only and the scene has none: remove it",
                )
            elif getattr(s.solvers.mpm, "transfer", "apic") == "flip":
                err(
                    base + ("cpic",),
                    "cpic: true needs solvers.mpm.transfer: apic (FLIP's increment is not masked)",
                )
        if c.type == "Mesh" or getattr(c, "restitution", 0.0) > 0:
            from simcli.collider_mesh import check_collider

            for p, msg in check_collider(c, s, loaded.scene_dir):
                err(base + p, msg)
    _check_collider_motion(loaded, ok_dom, err)
    from simcli.rigid.checks import check_rigid_bodies  # rigid_bodies: names, shapes, overlaps

    check_rigid_bodies(loaded, err)

    # entities
    seen: dict[str, int] = {}
    n_particles = 0
    n_sph = 0
    fem_v = fem_t = 0
    mpm = s.solvers.mpm
    sph = s.solvers.sph
    for i, e in enumerate(s.entities):
        base = ("entities", i)
        if e.name in seen:
            err(
                base + ("name",),
                f"duplicate entity name '{e.name}' (also entities.{seen[e.name]}.name); names must be unique",
            )
        else:
            seen[e.name] = i
        need_len(base + ("velocity",), e.velocity)
        if e.family == "SF":
            _check_sf_entity(e, base, dim, need_len, err)
        m = e.morph
        mpath = base + ("morph",)
        if m is None:  # only SF entities may omit it (models.py)
            continue
        if e.family == "FEMCloth":  # thin shells check their own morphs (simcli.solvers.fem.cloth.checks)
            from simcli.solvers.fem.checks import check_cloth_entity as cloth_check

            for p, msg in cloth_check(e, dim, loaded.scene_dir, s):
                err(base + p, msg)
            continue
        if m.type in ("Rectangle", "Line") and e.family != "PBD":
            err(
                mpath + ("type",),
                f"{m.type} morphs are for PBD entities (cloth, rods); {e.material.type} "
                "entities take Box, Sphere, Cylinder or Mesh",
            )
            continue
        if e.family == "PBD":  # sheets, polylines and open meshes: the PBD family checks its own morphs
            from simcli.solvers.pbd.config import check_entity

            for p, msg in check_entity(
                e, dim, loaded.scene_dir, lo if ok_dom else None, hi, s.solvers.pbd, scene=s
            ):
                err(base + p, msg)
            continue
        if e.family == "SF" and m.type == "Mesh":
            err(mpath + ("type",), "SF.Smoke morphs are Box, Sphere or Cylinder (Mesh is not available)")
            continue
        if e.family == "FEM":  # 3D only; TetGen needed for Sphere, Cylinder and surface meshes
            from simcli.solvers.fem.checks import check_entity as fem_check

            found = fem_check(e, dim, loaded.scene_dir)
            for p, msg in found:
                err(base + p, msg)
            if found:
                continue
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
            from simcli.geometry.sampling import morph_bounds
            from simcli.scene.estimate import particle_count as estimate_particle_count  # no int64 overflow

            mlo, mhi = morph_bounds(m, loaded.scene_dir)
            if e.family == "MPM":
                n_particles += estimate_particle_count(m, mpm.spacing, dim, loaded.scene_dir)
            elif e.family == "SPH":
                n_sph += estimate_particle_count(m, sph.particle_size, dim, loaded.scene_dir)
            elif e.family == "FEM":
                from simcli.geometry.tetmesh import estimate_counts

                nv, nt = estimate_counts(e, s.solvers.fem, loaded.scene_dir)
                fem_v, fem_t = fem_v + nv, fem_t + nt
        except Exception as ex:  # mesh unreadable or not closed
            err(mpath + ("file",) if m.type == "Mesh" else mpath, str(ex))
            continue
        tol = 1e-9
        outside = [a for a in range(dim) if mlo[a] < lo[a] - tol or mhi[a] > hi[a] + tol]
        if outside:
            axes = ", ".join("xyz"[a] for a in outside)
            err(
                mpath,
                f"entity '{e.name}' extends outside the domain along {axes} (its bounds "
                f"{_fmt(mlo)}..{_fmt(mhi)}, domain {_fmt(lo)}..{_fmt(hi)}); move it or enlarge domain",
            )

    _check_faces_and_sf(s, err)
    # solvers.fem.element: tet10 (FEM.Elastic only); solvers.fem.linear_solver: cholmod (FEM.Cloth)
    from simcli.solvers.fem.checks import check_element, check_linear_solver

    for p, msg in check_element(s) + check_linear_solver(s):
        err(p, msg)
    if s.probes:
        from simcli.probes.config import check_probes

        check_probes(s, err)
    if s.emitters or s.sinks:
        from simcli.scene.sources import check_sources

        check_sources(s, err)
    from simcli.scene.output_fields import check_output_fields

    check_output_fields(s, err)
    sph_rho = sorted({e.material.rho for e in s.entities if e.family == "SPH"})
    if sph.pressure_solver == "DFSPH" and not sph.clamp_pressure and len(sph_rho) > 1:
        err(
            ("solvers", "sph", "clamp_pressure"),
            "DFSPH with clamp_pressure: false (its conjugate-gradient solve) does not support liquids of "
            f"different rest densities (rho: {sph_rho}): its pressure operator is symmetric only for one "
            "rest density. Use clamp_pressure: true (a free surface), pressure_solver: WCSPH, or one rho "
            "for every SPH.Liquid",
        )
    from simcli.scene.limits import check_limits  # bounds, names, stability, overlaps (docs/LIMITS.md)

    errors += check_limits(loaded, geometry_ok=not errors)
    if errors:
        return sort_lines(errors)

    # memory estimate, before anything is allocated (scene/resources.py: counts from the morphs alone)
    from simcli.scene.resources import estimate_memory, memory_problem

    found = memory_problem(estimate_memory(s, loaded.scene_dir))
    if found:
        err(*found)
    from simcli.scene.limits import check_stability  # a fixed substep over the stability limit

    return errors or check_stability(loaded)


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"


# Largest SF grid the solver indexes (i32 indices, one field of this many cells)
_SF_MAX_CELLS = 2**31 - 1


def _check_sf_entity(e, base: tuple, dim: int, need_len, err) -> None:
    if e.velocity_field is not None and len(e.velocity_field) != dim:
        err(
            base + ("velocity_field",),
            f"expected {dim} expressions for dim {dim} (got {len(e.velocity_field)})",
        )
    for j, jet in enumerate(e.jets):
        jpath = base + ("jets", j)
        for key, vec in jet.vectors().items():
            need_len(jpath + tuple(key.split(".")), vec)
        if jet.path is not None and jet.path.type == "waypoints":
            for k, pt in enumerate(jet.path.points):
                need_len(jpath + ("path", "points", k), pt)
        if jet.path is not None and jet.path.type == "orbit" and dim == 2 and jet.path.axis != "z":
            err(jpath + ("path", "axis"), "a 2D orbit turns about z (the normal of the plane)")


def _check_faces_and_sf(s, err) -> None:
    """Open and periodic faces are for grid fluids only; periodic faces come in pairs; the SF grid is sane."""
    dim = s.sim.dim
    fams = s.families
    grid_only = ("open", "periodic")
    particle_fams = sorted(f for f in fams if f != "SF")
    faces = {"xyz"[a] + sign: s.domain.face("xyz"[a] + sign) for a in range(dim) for sign in "-+"}
    for name, b in faces.items():
        if b.type in grid_only and particle_fams:
            path = (
                ("domain", "faces", name, "type")
                if name in s.domain.faces
                else ("domain", "boundary", "type")
            )
            err(
                path,
                f"'{b.type}' faces are for grid fluids (SF) only; {', '.join(particle_fams)} entities need "
                "slip, sticky or separate",
            )
        if b.type in grid_only and b.velocity is not None and any(v != 0 for v in b.velocity):
            path = ("domain", "faces", name, "velocity") if name in s.domain.faces else ("domain", "boundary")
            err(path, f"a {b.type} face has no wall velocity (remove it)")
    for a in range(dim):
        lo_p, hi_p = (faces["xyz"[a] + sign].type == "periodic" for sign in "-+")
        if lo_p != hi_p:
            err(
                ("domain", "faces"),
                f"periodic faces come in pairs: {'xyz'[a]}- and {'xyz'[a]}+ must both be "
                "periodic (or neither)",
                key=True,
            )
    if "SF" not in fams:
        return
    sf_ents = [i for i, e in enumerate(s.entities) if e.family == "SF"]
    if len(sf_ents) > 1:
        err(
            ("entities", sf_ents[1], "material", "type"),
            "a scene holds one SF.Smoke entity (the fluid fills the "
            f"whole domain; also entities.{sf_ents[0]})",
        )
    res = s.solvers.sf.resolution
    if isinstance(res, list) and len(res) != dim:
        err(
            ("solvers", "sf", "resolution"),
            f"expected one cell count per axis ({dim}) or a single number (got {len(res)})",
        )
        return
    lo, hi = s.domain.bounds(dim)
    if len(lo) != dim or len(hi) != dim or any(a >= b for a, b in zip(lo, hi)):
        return
    n, _ = s.solvers.sf.cells(lo, hi)
    if math.prod(n) > _SF_MAX_CELLS:
        err(
            ("solvers", "sf", "resolution"),
            f"{'x'.join(map(str, n))} cells exceed the {_SF_MAX_CELLS:,} a grid can index; lower it",
        )
    if min(n) < 2:
        err(
            ("solvers", "sf", "resolution"),
            f"every axis needs >= 2 cells (got {'x'.join(map(str, n))} for the "
            "domain's shape); raise resolution or give one count per axis",
        )
    for a in range(dim):
        if faces["xyz"[a] + "-"].type == "periodic" and n[a] % 2:
            err(
                ("solvers", "sf", "resolution"),
                f"a periodic axis needs an even number of cells ({'xyz'[a]}: {n[a]})",
            )


def _check_collider_motion(loaded, ok_dom: bool, err) -> None:
    """Collider names unique; each motion readable (keyframes in order, CSV columns) and keeping the
    collider's centre inside the domain for the whole run; moving colliders only where a family moves them."""
    from simcli.motion import MotionError, collider_centre, collider_motion, sample_times

    s = loaded.scene
    dim = s.sim.dim
    names: dict[str, int] = {}
    lo, hi = (np.asarray(b, float) for b in s.domain.bounds(dim))
    t_end = s.sim.n_steps * s.sim.dt
    for i, c in enumerate(s.colliders):
        base = ("colliders", i)
        if c.name is not None:
            if not re.fullmatch(r"[A-Za-z0-9_.-]+", c.name) or c.name.startswith("."):
                err(
                    base + ("name",),
                    f"collider name '{c.name}': use letters, digits, _, - and . (it names files)",
                )
            if c.name in {e.name for e in s.entities}:
                err(
                    base + ("name",),
                    f"collider name '{c.name}' is also an entity's name (both name vtk/<name>.pvd)",
                )
            if c.name in names:
                err(
                    base + ("name",),
                    f"duplicate collider name '{c.name}' (also colliders.{names[c.name]}.name)",
                )
            names.setdefault(c.name, i)
        if c.motion is None:
            continue
        unsupported = sorted(s.families - MOVING_COLLIDER_FAMILIES)
        if unsupported:
            err(
                base + ("motion",),
                f"moving colliders are implemented for "
                f"{', '.join(sorted(MOVING_COLLIDER_FAMILIES))} entities "
                f"only; this scene has {', '.join(unsupported)} entities (remove motion or those entities)",
                key=True,
            )
        try:
            motion = collider_motion(c, dim, loaded.scene_dir)
        except MotionError as e:
            err(base + ("motion",) + e.path, str(e))
            continue
        except ValueError as e:
            err(base + ("motion",), str(e))
            continue
        if c.type == "Plane" or not ok_dom or len(collider_centre(c, dim)) != dim:
            continue
        x0 = collider_centre(c, dim)[None, :]
        for t in sample_times(motion, t_end):
            x = motion.pose(t).to_world(x0)[0]
            if np.any(x < lo) or np.any(x > hi):
                err(
                    base + ("motion",),
                    f"the collider's centre leaves the domain at t = {t:.4g} s (it reaches "
                    f"{np.array2string(x, precision=4, separator=', ')}; domain {lo.tolist()} .. "
                    f"{hi.tolist()}); "
                    "change the motion or enlarge the domain",
                    key=True,
                )
                break


MOVING_COLLIDER_FAMILIES = {"MPM", "PBD", "FEM", "SPH", "SF", "FEMCloth"}
