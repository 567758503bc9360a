"""Validation measurements of FEM.Cloth runs (registered in simcli.verify.registry's MEASUREMENTS)."""

from __future__ import annotations

import numpy as np

from simcli.verify.registry import entity_group, measurement


@measurement("cloth_intersections")
def cloth_intersections(f, entity, others=(), spheres=(), boxes=(), floor=None, **_):
    """Per frame: the number of the sheet's edges crossing one of its non-adjacent triangles (an independent
    segment-triangle test, simcli.solvers.fem.cloth.geometry; with ``others``, the sheets of those entities
    too, as one mesh) plus the vertices inside any of ``spheres`` ([[cx, cy, cz, r], ...]) or ``boxes``
    ([[lower, upper], ...]) or below ``floor`` (z) [-]."""
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections

    xs, ts, n0 = [], [], 0
    for name in [entity, *others]:
        _, g = entity_group(f, name)
        xs.append(np.asarray(g["position"][...], dtype=np.float64))
        ts.append(np.asarray(g["cells"][...], dtype=np.int64) + n0)
        n0 += xs[-1].shape[1]
    x = np.concatenate(xs, axis=1)
    tris = np.concatenate(ts)
    out = []
    for k in range(len(x)):
        n = len(edge_triangle_intersections(x[k], tris))
        for s in spheres:
            n += int((np.linalg.norm(x[k] - np.asarray(s[:3]), axis=1) < s[3]).sum())
        for lo, hi in boxes:
            n += int(np.all((x[k] > np.asarray(lo)) & (x[k] < np.asarray(hi)), axis=1).sum())
        if floor is not None:
            n += int((x[k][:, 2] < floor).sum())
        out.append(n)
    return f["time"][: len(out)], np.asarray(out, dtype=np.float64)


@measurement("max_speed")
def max_speed(f, entity, **_):
    """Largest vertex speed [m/s] per frame (needs the velocity output field)."""
    _, g = entity_group(f, entity)
    v = np.asarray(g["velocity"][...], dtype=np.float64)
    return f["time"][: len(v)], np.linalg.norm(v, axis=2).max(axis=1)
