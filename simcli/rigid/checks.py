"""Scene checks of ``rigid_bodies`` (no Taichi): each problem is an error line with the key's location
(exit 65): names (file names, unique among rigid bodies, colliders and entities), dimensions, degrees of
freedom that do not exist in 2D, a body outside the domain or overlapping an entity, a collider or another
body at the start, and families whose colliders do not move yet."""

from __future__ import annotations

import re
from typing import Any

import numpy as np

RIGID_FAMILIES = {"MPM", "PBD", "FEM", "SPH", "FEMCloth"}  # families whose colliders move and report loads


def _lattice(lo, hi, n: int) -> np.ndarray:
    axes = [lo[a] + (np.arange(n) + 0.5) * (hi[a] - lo[a]) / n for a in range(len(lo))]
    return np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)


def _inside(morph, sdf, x: np.ndarray) -> np.ndarray:
    """Points x inside a body's shape: a primitive's exact test, a Mesh's signed-distance grid."""
    from simcli.geometry.regions import points_in_shape

    if sdf is not None:
        return sdf.sample(x) < 0
    return points_in_shape(morph, x)


def _check_mesh_body(loaded: Any, rb, base: tuple, err):
    """A Mesh body's own checks (dim 3, families that meet a Mesh, a closed readable surface thicker than two
    cells of its grid); returns its signed-distance grid, or None after an error."""
    s = loaded.scene
    path = base + ("morph",)
    if s.sim.dim == 2:
        return _check_polygon_body(loaded, rb, base, err)
    if "SF" in s.families:
        err(
            path + ("type",),
            "Mesh rigid bodies meet MPM, PBD, FEM and SPH entities (as Mesh colliders do); this scene has SF "
            "entities: use a Box, Sphere or Cylinder body",
        )
        return None
    for key in ("rotate", "translate"):
        if len(getattr(rb.morph, key)) != 3:
            err(path + (key,), f"expected 3 components (got {len(getattr(rb.morph, key))})")
            return None
    from simcli.rigid.body import mesh_mass_properties, mesh_sdf

    try:
        sdf = mesh_sdf(rb, s, loaded.scene_dir)
        mesh_mass_properties(sdf.vertices, sdf.triangles, float(rb.rho))
    except (ValueError, OSError) as ex:
        msg = str(ex).replace("Filling a mesh with particles needs", "A Mesh rigid body needs")
        err(path + ("file",), msg.replace(" or use a tetrahedral mesh", ""))
        return None
    lo, hi = sdf.bounds
    if np.min(hi - lo) < 2 * sdf.h:
        err(
            path + ("file",),
            f"the mesh is thinner ({np.min(hi - lo):.3g} m) than two cells of its signed-distance grid "
            f"({sdf.h:.3g} m): material would pass through it; thicken it or set sdf_cell below "
            f"{np.min(hi - lo) / 2:.3g}",
        )
        return None
    return sdf


POLYGON_FAMILIES = {"MPM", "SPH"}  # families a 2D Mesh (polygon) body meets so far


def _check_polygon_body(loaded: Any, rb, base: tuple, err):
    """A 2D Mesh body (a closed polygon, simcli.rigid.polygon): families, the transform's keys, a readable
    simple outline thicker than two cells of its grid; returns its PolygonSDF, or None after an error."""
    s = loaded.scene
    path = base + ("morph",)
    other = sorted(s.families - POLYGON_FAMILIES)
    if other:
        err(
            path + ("type",),
            f"2D Mesh rigid bodies meet {' and '.join(sorted(POLYGON_FAMILIES))} entities so far; this scene "
            f"has {', '.join(other)} entities: use a Box or a Sphere body in 2D",
        )
        return None
    m = rb.morph
    if len(m.rotate) not in (1, 3) or (len(m.rotate) == 3 and any(abs(a) > 0 for a in m.rotate[:2])):
        err(path + ("rotate",), "in 2D, rotate is the angle about z [deg]: one number, or [0, 0, angle]")
        return None
    if len(m.translate) not in (2, 3) or (len(m.translate) == 3 and m.translate[2] != 0):
        err(path + ("translate",), "in 2D, translate is [x, y] (a third component must be 0)")
        return None
    if not isinstance(m.scale, (int, float)) and len(m.scale) not in (2, 3):
        err(path + ("scale",), f"expected 1, 2 or 3 components (got {len(m.scale)})")
        return None
    from simcli.rigid.polygon import build_polygon_sdf, polygon_mass_properties

    try:
        sdf = build_polygon_sdf(rb, s, loaded.scene_dir)
        polygon_mass_properties(sdf.vertices, float(rb.rho))
    except (ValueError, OSError) as ex:
        err(path + ("file",), str(ex))
        return None
    lo, hi = sdf.bounds
    if np.min(hi - lo) < 2 * sdf.h:
        err(
            path + ("file",),
            f"the polygon is thinner ({np.min(hi - lo):.3g} m) than two cells of its signed-distance grid "
            f"({sdf.h:.3g} m): material would pass through it; thicken it or set sdf_cell below "
            f"{np.min(hi - lo) / 2:.3g}",
        )
        return None
    return sdf


def check_rigid_bodies(loaded: Any, err) -> None:
    s = loaded.scene
    dim = s.sim.dim
    if not s.rigid_bodies:
        return
    unsupported = sorted(s.families - RIGID_FAMILIES)
    if unsupported:
        err(
            ("rigid_bodies",),
            f"rigid bodies are coupled with {', '.join(sorted(RIGID_FAMILIES - {'FEMCloth'}))} entities only "
            f"(FEM.Cloth included; their colliders move and report loads); this scene has "
            f"{', '.join(unsupported)} entities: remove "
            "rigid_bodies or those entities",
            key=True,
        )
    ents = {e.name for e in s.entities}
    cols = {c.name for c in s.colliders if c.name is not None}
    seen: dict[str, int] = {}
    lo, hi = (np.asarray(b, float) for b in s.domain.bounds(dim))
    ok_shapes = []
    for i, rb in enumerate(s.rigid_bodies):
        base = ("rigid_bodies", i)
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", rb.name) or rb.name.startswith("."):
            err(
                base + ("name",),
                f"rigid body name '{rb.name}': use letters, digits, _, - and . (it names files)",
            )
        if rb.name in seen:
            err(
                base + ("name",),
                f"duplicate rigid body name '{rb.name}' (also rigid_bodies.{seen[rb.name]}.name)",
            )
        seen.setdefault(rb.name, i)
        if rb.name in ents:
            err(
                base + ("name",),
                f"rigid body name '{rb.name}' is also an entity's name (both name vtk/<name>.pvd)",
            )
        if rb.name in cols:
            err(base + ("name",), f"rigid body name '{rb.name}' is also a collider's name")
        ok = True
        m = rb.morph
        for key in ("center", "size", "lower", "upper"):
            v = getattr(m, key, None)
            if v is not None and len(v) != dim:
                err(base + ("morph", key), f"expected {dim} components for dim {dim} (got {len(v)})")
                ok = False
        if m.type == "Cylinder" and dim == 2:
            err(base + ("morph", "type"), "Cylinder rigid bodies need dim 3 (a Sphere is a disk in 2D)")
            ok = False
        sdf = None
        if m.type == "Mesh":
            sdf = _check_mesh_body(loaded, rb, base, err)
            ok = ok and sdf is not None
        if rb.cpic:  # CPIC bodies (docs/RIGID.md): an MPM feature of the APIC transfer, on thin Boxes
            if m.type != "Box":
                err(
                    base + ("cpic",),
                    f"cpic: true is for Box bodies (a plate along its thinnest axis), not {m.type}",
                )
            elif not any(str(e.material.type).startswith("MPM.") for e in s.entities):
                err(
                    base + ("cpic",),
                    "cpic: true acts on MPM materials only and the scene has none: remove it",
                )
            elif getattr(s.solvers.mpm, "transfer", "apic") == "flip":
                err(
                    base + ("cpic",),
                    "cpic: true needs solvers.mpm.transfer: apic (FLIP's increment is not masked)",
                )
        if rb.velocity is not None and len(rb.velocity) != dim:
            err(base + ("velocity",), f"expected {dim} components for dim {dim} (got {len(rb.velocity)})")
        na = 1 if dim == 2 else 3
        if rb.angular_velocity is not None and len(rb.angular_velocity) != na:
            err(
                base + ("angular_velocity",),
                f"expected {na} component{'s' if na > 1 else ''} for dim {dim} (got "
                f"{len(rb.angular_velocity)})",
            )
        if dim == 2:
            bad = [d for d in rb.fixed_dofs if d in ("z", "rx", "ry")]
            if bad:
                err(
                    base + ("fixed_dofs",),
                    f"unknown degree(s) of freedom {', '.join(bad)} in 2D (a 2D body has x, y and rz)",
                )
        if not ok:
            continue
        blo, bhi = (np.asarray(b, float)[:dim] for b in (sdf.bounds if sdf is not None else m.bounds()))
        if np.any(blo < lo) or np.any(bhi > hi):
            err(
                base + ("morph",),
                f"the body ({blo.tolist()} .. {bhi.tolist()}) is not inside the domain ({lo.tolist()} .. "
                f"{hi.tolist()}): move it or enlarge the domain",
            )
        ok_shapes.append((i, rb, blo, bhi, sdf))
    n = 24 if dim == 3 else 96
    for k, (i, rb, blo, bhi, sdf) in enumerate(ok_shapes):
        base = ("rigid_bodies", i, "morph")
        others = [
            (f"entity '{e.name}' (entities.{j})", e.morph)
            for j, e in enumerate(s.entities)
            if e.morph is not None and e.morph.type in ("Box", "Sphere", "Cylinder") and e.family != "SF"
        ]
        others = [(what, om, None, None, None) for what, om in others]
        others += [
            (f"rigid body '{o.name}' (rigid_bodies.{j})", o.morph, olo, ohi, osdf)
            for j, o, olo, ohi, osdf in ok_shapes[k + 1 :]
        ]
        for what, om, olo, ohi, osdf in others:
            if olo is None:
                try:
                    olo, ohi = (np.asarray(b, float)[:dim] for b in om.bounds())
                except (TypeError, ValueError):
                    continue
            a, b = np.maximum(blo, olo), np.minimum(bhi, ohi)
            if np.any(b <= a):
                continue
            x = _lattice(a, b, n)
            both = _inside(rb.morph, sdf, x) & _inside(om, osdf, x)
            vol = float(both.mean() * np.prod(b - a))
            if vol > 1e-6 * float(np.prod(bhi - blo)):  # touching is not overlapping
                err(
                    base,
                    f"rigid body '{rb.name}' overlaps {what} at the start (about {vol:.3g} "
                    f"{'m^3' if dim == 3 else 'm^2'}): move one of them apart",
                )
        x = _lattice(blo, bhi, n)
        x = x[_inside(rb.morph, sdf, x)]
        from simcli.scene.limits import _collider_inside

        for ci, c in enumerate(s.colliders):
            if len(x) and c.motion is None and _collider_inside(c, x).any():
                err(base, f"rigid body '{rb.name}' overlaps colliders.{ci} ({c.type}) at the start: move it")
