"""Validate-time checks of FEM.Cloth entities (numpy, no Taichi): morph type, mesh quality, thickness vs
contact distance, initial intersections (with itself, colliders, walls)."""

from __future__ import annotations

import numpy as np

from simcli.solvers.fem.cloth.config import MORPHS


def cholmod_available() -> bool:
    """Whether the optional CHOLMOD backend (solvers.fem.linear_solver) can run: cvxopt (its CHOLMOD) and
    threadpoolctl (to hold its BLAS to the run's threads)."""
    import importlib.util

    return all(importlib.util.find_spec(m) is not None for m in ("cvxopt", "threadpoolctl"))


def check_entity(e, dim: int, scene_dir, scene) -> list[tuple[tuple, str]]:
    """(path below the entity, message) per problem."""
    if dim != 3:
        return [(("material", "type"), "FEM.Cloth entities need a 3D scene (sim.dim: 3)")]
    m = e.morph
    if m.type not in MORPHS:
        return [
            (("morph", "type"), f"FEM.Cloth takes Rectangle or triangle Mesh morphs (a sheet); got {m.type}")
        ]
    if m.type == "Rectangle" and len(m.center) != 3:
        return [(("morph", "center"), f"expected 3 components for dim 3 (got {len(m.center)})")]
    bad = [
        (i, c.type)
        for i, c in enumerate(scene.colliders)
        if c.type not in ("Plane", "Box", "Sphere", "Cylinder", "Mesh")
    ]
    if bad:
        return [
            (
                ("material", "type"),
                f"FEM.Cloth meets Plane, Box, Sphere, Cylinder and Mesh colliders; "
                f"colliders.{bad[0][0]} is a {bad[0][1]}: replace it by those shapes or use PBD.Cloth",
            )
        ]
    mat = e.material
    nreg = len(e.fixed_regions)
    if mat.fixed_velocity is not None and mat.fixed_motion is not None:
        return [
            (
                ("material", "fixed_motion"),
                "give fixed_velocity (one translation for every fixed region) or fixed_motion (one motion "
                "per region), not both",
            )
        ]
    for key in ("fixed_velocity", "fixed_motion"):
        if getattr(mat, key) is not None and nreg == 0:
            return [
                (
                    ("material", key),
                    f"{key} moves the vertices held by `fixed`, but the entity has no "
                    "`fixed` region: add one or remove it",
                )
            ]
    if mat.fixed_motion is not None and len(mat.fixed_motion) not in (1, nreg):
        return [
            (
                ("material", "fixed_motion"),
                f"fixed_motion has {len(mat.fixed_motion)} motions for {nreg} fixed region(s): give one per "
                "region (in the order of `fixed`) or one for all",
            )
        ]
    from simcli.motion import MotionError
    from simcli.solvers.fem.cloth.model import mesh_problems
    from simcli.solvers.fem.cloth.obstacles import Obstacles
    from simcli.solvers.fem.cloth.topology import cloth_mesh

    try:
        x, t = cloth_mesh(e, scene_dir)
    except Exception as ex:
        return [(("morph", "file") if m.type == "Mesh" else ("morph",), str(ex))]
    out = [(("morph",), f"{p}; repair the mesh (simcli repair) or give another") for p in mesh_problems(x, t)]
    if out:
        return out
    dhat = float(scene.solvers.fem.contact_distance)
    edge = np.linalg.norm(x[t[:, 1]] - x[t[:, 0]], axis=1)
    if dhat >= 0.5 * float(edge.min()):
        out.append(
            (
                ("morph",),
                f"solvers.fem.contact_distance {dhat:g} m is not below half the shortest edge "
                f"({float(edge.min()):g} m): neighbouring vertices would repel at rest; lower "
                "contact_distance or coarsen the mesh",
            )
        )
    if e.material.thickness > dhat:
        out.append(
            (
                ("material", "thickness"),
                f"thickness {e.material.thickness:g} m is larger than solvers.fem.contact_distance "
                f"({dhat:g} m): contact keeps layers up to contact_distance apart, so they would come closer "
                f"than the shell is thick; raise contact_distance to at least {e.material.thickness:g} m or "
                "thin the shell",
            )
        )
    lo, hi = scene.domain.bounds(3)
    if len(lo) != 3 or len(hi) != 3:  # reported by the domain checks
        return out
    try:  # the colliders at their pose at t = 0 (a bad motion is reported by the collider checks)
        obst = Obstacles(scene, scene_dir, mesh_boxes=False)  # Box, Cylinder: exact here
        d, _, _ = obst.distances(x, 0.0)
    except (MotionError, ValueError, IndexError):  # a collider with other than 3 components: collider checks
        return out
    bad = d <= 0
    if bad.any():
        k, i = np.argwhere(bad)[0]
        what = (
            ("domain wall " + ["x-", "x+", "y-", "y+", "z-", "z+"][k])
            if k < 6
            else f"colliders.{obst.index[k - 6]}"
        )
        out.append(
            (
                ("morph",),
                f"{int(bad.any(axis=0).sum())} vertex(es) start inside or on {what} (first at "
                f"{np.round(x[i], 6).tolist()}); the cloth must start outside every obstacle: move it",
            )
        )
    else:
        out += _sphere_face_problems(x, t, obst)
    if not out:  # what the solver keeps off: contact_distance, plus a Sphere's facet stand-off
        obst.set_facets(x, t)
        d, _, _ = obst.distances(x, 0.0)
        close = d < dhat
        if close.any():
            k, i = np.argwhere(close)[0]
            off = obst.offsets[k - 6] if k >= 6 else None
            if off is None:
                msg = (
                    f"vertex at {np.round(x[i], 6).tolist()} starts closer than solvers.fem.contact_distance "
                    f"({dhat:g} m) to an obstacle (distance {float(d[k, i]):.3g} m): move the cloth away"
                )
            else:
                gap, need = float(d[k, i] + off[i]), float(dhat + off[i])
                msg = (
                    f"vertex at {np.round(x[i], 6).tolist()} starts {gap:.3g} m from colliders."
                    f"{obst.index[k - 6]} (Sphere); a cloth vertex starts at least {need:.3g} m from a "
                    "sphere: "
                    f"solvers.fem.contact_distance ({dhat:g} m) plus the {float(off[i]):.3g} m its flat "
                    "triangles stand off it (sqrt(R^2 + r^2) - R, r a triangle's enclosing radius; a finer "
                    "mesh needs less): move the cloth away"
                )
            out.append((("morph",), msg))
    from simcli.solvers.fem.cloth.mesh_obstacles import MESH_TYPES

    if not out and (
        any(c.type in MESH_TYPES for c in scene.colliders) or getattr(scene, "rigid_bodies", None)
    ):
        from simcli.solvers.fem.cloth.mesh_obstacles import initial_problems

        try:  # a Mesh collider's own problems (file, closed surface) are reported by the collider checks
            out += [(("morph",), msg) for msg in initial_problems(x, t, scene, scene_dir, dhat)]
        except (ValueError, IndexError, OSError, ArithmeticError, MotionError):
            pass
    if not out:
        out += _solid_problems(x, scene, dhat)
    if not out:
        out += _solid_mesh_problems(x, t, scene, scene_dir, dhat)
    if not out:
        import ipctk

        cm = ipctk.CollisionMesh(x, ipctk.edges(t), t)
        if ipctk.has_intersections(cm, x):
            # locate one: an edge crossing a triangle
            loc = _first_intersection(x, t)
            out.append(
                (
                    ("morph",),
                    f"the cloth intersects itself at the start{loc}: untangle the mesh",
                )
            )
    return out


def _sphere_face_problems(x, t, obst) -> list[tuple[tuple, str]]:
    """A cloth triangle through a Sphere collider at t = 0 whose vertices all lie outside it (the vertex test
    above passes it): the exact distance from the centre to the triangles."""
    from simcli.collider_mesh import point_triangle_distance

    out = []
    A, B, C = (x[t[:, j]] for j in range(3))
    for k, c in enumerate(obst.specs):
        if c.kind != "Sphere":
            continue
        P = obst._pose(6 + k, 0.0)
        ctr = np.asarray(c.a, float)
        if P is not None:
            ctr = P.to_world(ctr[None, :])[0]
        dt = point_triangle_distance(np.broadcast_to(ctr, A.shape), A, B, C)
        j = int(np.argmin(dt))
        if dt[j] < c.radius:
            near = np.round((A[j] + B[j] + C[j]) / 3.0, 6).tolist()
            out.append(
                (
                    ("morph",),
                    f"the cloth intersects colliders.{obst.index[k]} (Sphere) at the start (near {near}); "
                    "move the cloth out of it",
                )
            )
    return out


def _first_intersection(x, t) -> str:
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections

    hits = edge_triangle_intersections(x, t, first_only=True)
    if not hits:
        return ""
    return f" (near {np.round(hits[0][2], 6).tolist()})"


def _solid_problems(x, scene, dhat: float) -> list[tuple[tuple, str]]:
    """A cloth vertex inside, or closer than contact_distance to, an FEM solid's Box, Sphere or Cylinder morph
    at t = 0 (the solid meets the cloth in its IPC step: solid_obstacles.py; Mesh morphs:
    _solid_mesh_problems)."""
    from simcli.solvers.fem.cloth.obstacles import Spec, _sdf

    out = []
    for j, e in enumerate(scene.entities):
        m = e.morph
        if e.family != "FEM" or m is None or m.type not in ("Box", "Sphere", "Cylinder"):
            continue
        try:
            if m.type == "Box":
                lo, hi = m.bounds()
                sp = Spec("Box", tuple(lo), tuple(hi))
            elif m.type == "Sphere":
                sp = Spec("Sphere", tuple(m.center), (0.0,) * 3, radius=float(m.radius))
            else:
                sp = Spec(
                    "Cylinder",
                    tuple(m.center),
                    (0.0,) * 3,
                    radius=float(m.radius),
                    half_height=0.5 * float(m.height),
                    axis="xyz".index(m.axis),
                )
            d, _ = _sdf(sp, x)
        except (TypeError, ValueError, AttributeError, IndexError):  # a malformed morph: its own checks
            continue
        if d.min() < dhat:
            i = int(np.argmin(d))
            what = "inside" if d[i] <= 0 else f"closer than solvers.fem.contact_distance ({dhat:g} m) to"
            out.append(
                (
                    ("morph",),
                    f"a vertex at {np.round(x[i], 6).tolist()} starts {what} the FEM solid '{e.name}' "
                    f"(entities.{j}, {m.type}); FEM.Cloth meets FEM solids in its contact: move the cloth "
                    "away",
                )
            )
    return out


def _solid_mesh_problems(x, t, scene, scene_dir, dhat: float) -> list[tuple[tuple, str]]:
    """The cloth (x, t) crossing, inside or within contact_distance of an FEM solid given as a Mesh morph at
    t = 0: the boundary of its tetrahedral file (.msh, ...) or its closed surface (which TetGen fills), as
    mesh_obstacles._initial_problem checks a Mesh collider's."""
    from simcli.solvers.fem.cloth.mesh_obstacles import _initial_problem

    out = []
    for j, e in enumerate(scene.entities):
        m = e.morph
        if e.family != "FEM" or m is None or m.type != "Mesh" or e.material.type == "FEM.Cloth":
            continue
        try:  # a bad file or an open surface is reported by the FEM checks
            from simcli.geometry.mesh import load_mesh_morph
            from simcli.geometry.tetmesh import boundary_faces, read_tets

            got = read_tets(m, scene_dir)
            if got is not None:
                X, tets = np.asarray(got[0], float), np.asarray(got[1], np.int64)
                faces = boundary_faces(tets, X)
                ids = np.unique(faces)
                remap = np.full(len(X), -1, np.int64)
                remap[ids] = np.arange(len(ids))
                V, T = X[ids], remap[faces]
            else:
                surf = load_mesh_morph(m, scene_dir)
                V, T = np.asarray(surf.vertices, float), np.asarray(surf.triangles, np.int64)
        except Exception:  # noqa: BLE001 (any problem of the file is the FEM checks' to report)
            continue
        if len(T) == 0 or V.shape[1:] != (3,):
            continue
        msg = _initial_problem(x, t, V, T, f"the FEM solid '{e.name}' (entities.{j}, Mesh)", dhat)
        if msg:
            out.append((("morph",), msg))
    return out
