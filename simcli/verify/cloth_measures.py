"""Validation measurements of FEM.Cloth runs (registered in simcli.verify.registry's MEASUREMENTS)."""

from __future__ import annotations

import numpy as np

from simcli.verify.registry import entity_group, measurement


@measurement("cloth_intersections")
def cloth_intersections(
    f,
    entity,
    others=(),
    spheres=(),
    boxes=(),
    floor=None,
    mesh_colliders=False,
    rigid_bodies=False,
    solids=(),
    **_,
):
    """Per frame: the number of the sheet's edges crossing one of its non-adjacent triangles (an independent
    segment-triangle test, simcli.solvers.fem.cloth.geometry; with ``others``, the sheets of those entities
    too, as one mesh) plus the triangles reaching inside any of ``spheres`` ([[cx, cy, cz, r], ...]: the exact
    distance from the centre to each triangle, so its edges and face count, not only its vertices), the
    vertices inside any of ``boxes`` ([[lower, upper], ...]) and those below ``floor`` (z) [-]. With
    ``mesh_colliders``, the scene's `type: Mesh` and `type: Box` colliders' triangles (a Box's 12) at their
    prescribed pose at the frame's time join the mesh tested (a cloth edge through a collider triangle or a
    collider edge through a cloth triangle counts), plus the cloth vertices inside them (ray parity). With
    ``rigid_bodies``, every rigid body's triangles (the ones FEM.Cloth meets:
    simcli.solvers.fem.cloth.mesh_obstacles.body_mesh) at the pose sim.h5 records for the frame
    (/rigid_bodies/<name>/position, orientation) are tested the same way, and with ``solids`` (FEM entity
    names) their boundary triangles at the frame's recorded positions."""
    from simcli.collider_mesh import point_triangle_distance
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections

    xs, ts, n0 = [], [], 0
    for name in [entity, *others]:
        _, g = entity_group(f, name)
        xs.append(np.asarray(g["position"][...], dtype=np.float64))
        ts.append(np.asarray(g["cells"][...], dtype=np.int64) + n0)
        n0 += xs[-1].shape[1]
    x = np.concatenate(xs, axis=1)
    tris = np.concatenate(ts)
    mo = _mesh_colliders(f) if mesh_colliders else None
    times = np.asarray(f["time"][: len(x)], dtype=np.float64)
    bodies = _rigid_body_meshes(f) if rigid_bodies else []
    for name in solids:  # an FEM solid: its boundary triangles, posed by its recorded vertex positions
        from simcli.geometry.tetmesh import boundary_faces

        _, gs = entity_group(f, name)
        xs_all = np.asarray(gs["position"][...], dtype=np.float64)
        tets = np.asarray(gs["cells"][...], dtype=np.int64)[:, :4]
        faces = boundary_faces(tets, xs_all[0])
        ids = np.unique(faces)
        remap = np.full(xs_all.shape[1], -1, np.int64)
        remap[ids] = np.arange(len(ids))
        # (body-frame vertices, triangles, pivot, positions, orientations): identity poses, per-frame vertices
        bodies.append((xs_all[:, ids], remap[faces], None, None, None))
    out = []
    for k in range(len(x)):
        n_body = 0
        if bodies:
            from simcli.geometry.mesh import TriMesh, points_inside_mesh
            from simcli.motion import quat_to_matrix

            for V0, Tb, piv, pos, quat in bodies:
                V = V0[k] if piv is None else (V0 - piv) @ quat_to_matrix(quat[k]).T + pos[k]
                n_body += len(
                    [
                        h
                        for h in edge_triangle_intersections(
                            np.concatenate([x[k], V]), np.concatenate([tris, Tb + n0])
                        )
                        if (h[0][0] < n0) != (h[1] < len(tris))  # cloth against body (the cloth's own: below)
                    ]
                )
                n_body += int(points_inside_mesh(TriMesh(V, Tb, 1.0, "body"), x[k]).sum())
        if mo is not None and mo.m:
            from simcli.geometry.mesh import TriMesh, points_inside_mesh

            V = mo.positions(float(times[k]))
            n = len(edge_triangle_intersections(np.concatenate([x[k], V]), np.concatenate([tris, mo.T + n0])))
            for j in range(len(mo.index)):
                lo, hi = mo.offsets[j], mo.offsets[j + 1]
                Tj = mo.T[(mo.T >= lo).all(axis=1) & (mo.T < hi).all(axis=1)] - lo
                n += int(points_inside_mesh(TriMesh(V[lo:hi], Tj, 1.0, "collider"), x[k]).sum())
        else:
            n = len(edge_triangle_intersections(x[k], tris))
        for s in spheres:  # the triangles reaching inside (a vertex inside is such a triangle's too)
            c = np.broadcast_to(np.asarray(s[:3], dtype=np.float64), (len(tris), 3))
            A, B, C = (x[k][tris[:, j]] for j in range(3))
            n += int((point_triangle_distance(c, A, B, C) < s[3]).sum())
        for lo, hi in boxes:
            n += int(np.all((x[k] > np.asarray(lo)) & (x[k] < np.asarray(hi)), axis=1).sum())
        if floor is not None:
            n += int((x[k][:, 2] < floor).sum())
        out.append(n + n_body)
    return f["time"][: len(out)], np.asarray(out, dtype=np.float64)


def _rigid_body_meshes(f):
    """(body-frame vertices, triangles, centre of mass in the body frame, positions (frames, 3), orientations
    (frames, 4)) of every rigid body of the run, as FEM.Cloth meets them."""
    from simcli.rigid.body import RigidBodyModel
    from simcli.solvers.fem.cloth.mesh_obstacles import body_mesh
    from simcli.verify.registry import scene_of

    scene, scene_dir = scene_of(f), _scene_dir(f)
    dhat = float(scene.solvers.fem.contact_distance)
    out = []
    for rb in getattr(scene, "rigid_bodies", None) or []:
        V, T = body_mesh(rb, scene, scene_dir, dhat)
        piv = RigidBodyModel(rb, 3, scene, scene_dir).pivot
        g = f["rigid_bodies"][rb.name]
        out.append(
            (V, T, piv, np.asarray(g["position"][...], float), np.asarray(g["orientation"][...], float))
        )
    return out


def _scene_dir(f):
    import json
    from pathlib import Path

    try:
        run = Path(f.filename).parent / "run.json"
        return Path(json.loads(run.read_text())["scene"]).resolve().parent
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _mesh_colliders(f):
    """The run's Mesh and Box colliders (simcli.solvers.fem.cloth.mesh_obstacles.MeshObstacles), files
    relative to the scene's folder (run.json next to sim.h5 names the scene)."""
    import json
    from pathlib import Path

    from simcli.solvers.fem.cloth.mesh_obstacles import MeshObstacles
    from simcli.verify.registry import scene_of

    scene_dir = None
    try:
        run = Path(f.filename).parent / "run.json"
        scene_dir = Path(json.loads(run.read_text())["scene"]).resolve().parent
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return MeshObstacles(scene_of(f), scene_dir)


@measurement("max_speed")
def max_speed(f, entity, **_):
    """Largest vertex speed [m/s] per frame (needs the velocity output field)."""
    _, g = entity_group(f, entity)
    v = np.asarray(g["velocity"][...], dtype=np.float64)
    return f["time"][: len(v)], np.linalg.norm(v, axis=2).max(axis=1)
