"""PBD scene checks (numpy, no Taichi): what ``simcli validate`` reports about a PBD entity, from its
morph and the mesh the solver would build (``topology.mesh_for_entity``)."""

from __future__ import annotations

from simcli.solvers.pbd.config import MORPHS
from simcli.solvers.pbd.topology import mesh_for_entity


def check_entity(e, dim: int, scene_dir, lo, hi, opts=None) -> list[tuple[tuple, str]]:
    """Semantic checks of a PBD entity: (path below the entity, message) per problem."""
    out: list[tuple[tuple, str]] = []
    m = e.morph
    if dim != 3:
        return [(("material", "type"), f"{e.material.type} entities need a 3D scene (sim.dim: 3)")]
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
        for f in ("lower", "upper", "center", "size"):
            v = getattr(r, f, None)
            if v is not None and len(v) != 3:
                out.append((rpath + (f,), f"expected 3 components for dim 3 (got {len(v)})"))
    for f in ("lower", "upper", "size") if m.type == "Box" else ():
        v = getattr(m, f, None)
        if v is not None and len(v) != 3:
            out.append((("morph", f), f"expected 3 components for dim 3 (got {len(v)})"))
    if m.type in ("Rectangle", "Sphere", "Cylinder") and len(m.center) != 3:
        out.append((("morph", "center"), f"expected 3 components for dim 3 (got {len(m.center)})"))
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
        x = mesh_for_entity(e, scene_dir, opts).x
    except Exception as ex:  # noqa: BLE001 - unreadable mesh file, no triangles, no tetgen: all reported
        return [(("morph",) + (("file",) if m.type == "Mesh" else ()), str(ex))]
    if lo is not None:
        bad = [a for a in range(3) if x[:, a].min() < lo[a] - 1e-9 or x[:, a].max() > hi[a] + 1e-9]
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


def _polyline_length(points) -> float:
    import numpy as np

    p = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
