"""Independent exact-enough intersection test of a triangle mesh with itself: every edge against every
triangle that shares no vertex with it (segment-triangle, Moller-Trumbore), bounding boxes first.
Used by validate (the location of an initial intersection) and by the tests and verify cases."""

from __future__ import annotations

import numpy as np


def edge_triangle_intersections(x: np.ndarray, tris: np.ndarray, first_only: bool = False, cell: float = 0.0):
    """[(edge (a, b), triangle index, point)] for segments crossing non-adjacent triangles."""
    e = np.unique(
        np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1), axis=0
    )
    tlo, thi = x[tris].min(axis=1), x[tris].max(axis=1)
    elo, ehi = np.minimum(x[e[:, 0]], x[e[:, 1]]), np.maximum(x[e[:, 0]], x[e[:, 1]])
    h = cell or float(np.median(np.linalg.norm(x[e[:, 1]] - x[e[:, 0]], axis=1))) * 2
    # uniform grid hash of the triangles' boxes
    from collections import defaultdict

    grid = defaultdict(list)
    lo_c = np.floor(tlo / h).astype(np.int64)
    hi_c = np.floor(thi / h).astype(np.int64)
    for k in range(len(tris)):
        for i in range(lo_c[k, 0], hi_c[k, 0] + 1):
            for j in range(lo_c[k, 1], hi_c[k, 1] + 1):
                for m in range(lo_c[k, 2], hi_c[k, 2] + 1):
                    grid[(i, j, m)].append(k)
    pe, pt = [], []
    elo_c = np.floor(elo / h).astype(np.int64)
    ehi_c = np.floor(ehi / h).astype(np.int64)
    for k in range(len(e)):
        cand = set()
        for i in range(elo_c[k, 0], ehi_c[k, 0] + 1):
            for j in range(elo_c[k, 1], ehi_c[k, 1] + 1):
                for m in range(elo_c[k, 2], ehi_c[k, 2] + 1):
                    cand.update(grid.get((i, j, m), ()))
        for c in cand:
            pe.append(k)
            pt.append(c)
    if not pe:
        return []
    pe, pt = np.array(pe), np.array(pt)
    ea, eb = e[pe, 0], e[pe, 1]
    tt = tris[pt]
    keep = ~((tt == ea[:, None]) | (tt == eb[:, None])).any(axis=1)
    keep &= np.all(elo[pe] <= thi[pt], axis=1) & np.all(ehi[pe] >= tlo[pt], axis=1)
    pe, pt, ea, eb, tt = pe[keep], pt[keep], ea[keep], eb[keep], tt[keep]
    o, dvec = x[ea], x[eb] - x[ea]
    v0, v1, v2 = x[tt[:, 0]], x[tt[:, 1]], x[tt[:, 2]]
    e1, e2 = v1 - v0, v2 - v0
    pv = np.cross(dvec, e2)
    det = np.einsum("ij,ij->i", e1, pv)
    ok = np.abs(det) > 1e-30
    inv = np.where(ok, 1 / np.where(ok, det, 1), 0)
    tv = o - v0
    u = np.einsum("ij,ij->i", tv, pv) * inv
    qv = np.cross(tv, e1)
    v = np.einsum("ij,ij->i", dvec, qv) * inv
    s = np.einsum("ij,ij->i", e2, qv) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (s >= 0) & (s <= 1)
    idx = np.nonzero(hit)[0]
    out = [((int(ea[k]), int(eb[k])), int(pt[k]), o[k] + s[k] * dvec[k]) for k in idx]
    return out[:1] if first_only else out
