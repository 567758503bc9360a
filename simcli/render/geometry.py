"""Shapes to draw, in plain numpy: surface triangles of tetrahedral meshes, triangulated collider surfaces
(3D), collider outlines (2D and the side projection of 3D grids), and Lambert shading."""

from __future__ import annotations

import numpy as np

_AX = {"x": 0, "y": 1, "z": 2}


def tet_surface(cells: np.ndarray) -> np.ndarray:
    """Triangles that belong to exactly one tetrahedron (the boundary of the mesh), (m, 3)."""
    c = np.asarray(cells, dtype=np.int64)
    if c.size == 0:
        return np.zeros((0, 3), np.int64)
    faces = np.concatenate([c[:, [1, 2, 3]], c[:, [0, 3, 2]], c[:, [0, 1, 3]], c[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, idx, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[idx[counts == 1]]


def shade(tris: np.ndarray, light=(0.4, -0.6, 0.7)) -> np.ndarray:
    """Two-sided Lambert factor in [0.35, 1] per triangle; tris is (m, 3, 3)."""
    if len(tris) == 0:
        return np.zeros(0)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    ln = np.linalg.norm(n, axis=1)
    ln[ln == 0] = 1.0
    l_ = np.asarray(light, float)
    l_ = l_ / np.linalg.norm(l_)
    return 0.35 + 0.65 * np.abs(n @ l_) / ln


def _sphere(center, r, n=24):
    th = np.linspace(0, np.pi, n // 2 + 1)
    ph = np.linspace(0, 2 * np.pi, n + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    pts = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1) * r + np.asarray(center)
    return _grid_tris(pts)


def _grid_tris(pts: np.ndarray) -> np.ndarray:
    a, b = pts[:-1, :-1], pts[1:, :-1]
    c, d = pts[1:, 1:], pts[:-1, 1:]
    t1 = np.stack([a, b, c], axis=-2).reshape(-1, 3, 3)
    t2 = np.stack([a, c, d], axis=-2).reshape(-1, 3, 3)
    return np.concatenate([t1, t2])


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[hi[i] if (k >> i) & 1 else lo[i] for i in range(3)] for k in range(8)])
    quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return np.array(
        [[v[q[0]], v[q[1]], v[q[2]]] for q in quads] + [[v[q[0]], v[q[2]], v[q[3]]] for q in quads]
    )


def _cylinder(center, r, h, axis, n=32):
    a = _AX.get(axis, 2)
    u, w = [i for i in range(3) if i != a]
    ph = np.linspace(0, 2 * np.pi, n + 1)
    s = np.linspace(-h / 2, h / 2, 2)
    P, S = np.meshgrid(ph, s, indexing="ij")
    pts = np.zeros(P.shape + (3,))
    pts[..., u], pts[..., w], pts[..., a] = r * np.cos(P), r * np.sin(P), S
    side = _grid_tris(pts + np.asarray(center))
    caps = []
    for z in (-h / 2, h / 2):
        c0 = np.zeros(3)
        c0[a] = z
        for i in range(n):
            p1, p2 = c0.copy(), c0.copy()
            p1[u], p1[w] = r * np.cos(ph[i]), r * np.sin(ph[i])
            p2[u], p2[w] = r * np.cos(ph[i + 1]), r * np.sin(ph[i + 1])
            caps.append([c0, p1, p2])
    return np.concatenate([side, np.asarray(caps) + np.asarray(center)])


def _plane_polygon(point, normal, lo, hi) -> np.ndarray:
    """The polygon where a plane cuts the box [lo, hi] (3D), ordered around its centre; (k, 3)."""
    p0, n = np.asarray(point, float), np.asarray(normal, float)
    n = n / (np.linalg.norm(n) or 1.0)
    corners = np.array([[hi[i] if (k >> i) & 1 else lo[i] for i in range(3)] for k in range(8)])
    d = (corners - p0) @ n
    pts = []
    for i in range(8):
        for j in range(i + 1, 8):
            if bin(i ^ j).count("1") != 1:
                continue
            if d[i] == 0:
                pts.append(corners[i])
            if d[i] * d[j] < 0:
                t = d[i] / (d[i] - d[j])
                pts.append(corners[i] + t * (corners[j] - corners[i]))
    if len(pts) < 3:
        return np.zeros((0, 3))
    pts = np.unique(np.round(np.asarray(pts), 12), axis=0)
    c = pts.mean(axis=0)
    e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    ang = np.arctan2((pts - c) @ e2, (pts - c) @ e1)
    return pts[np.argsort(ang)]


def collider_triangles(col: dict, lo, hi) -> np.ndarray:
    """A 3D collider's surface as triangles (m, 3, 3); empty for types this does not know."""
    t = col.get("type")
    try:
        if t == "Sphere":
            return _sphere(col["center"], float(col["radius"]))
        if t == "Box":
            return _box(col["lower"], col["upper"])
        if t == "Cylinder":
            return _cylinder(col["center"], float(col["radius"]), float(col["height"]), col.get("axis", "z"))
        if t == "Plane":
            poly = _plane_polygon(col["point"], col["normal"], lo, hi)
            return np.array([[poly[0], poly[i], poly[i + 1]] for i in range(1, len(poly) - 1)])
        if t == "Mesh":  # its triangles at t = 0 (the file relative to the scene's folder, data.open_run)
            from simcli.geometry.mesh import read_surface, resolve_mesh_path, transform_points

            V, T = read_surface(resolve_mesh_path(col["file"], col.get("_scene_dir")))
            x = transform_points(
                V, col.get("scale", 1.0), col.get("rotate", (0, 0, 0)), col.get("translate", (0, 0, 0))
            )
            return x[T]
    except (KeyError, TypeError, ValueError, OSError):
        pass
    return np.zeros((0, 3, 3))


def collider_outline_2d(col: dict, lo, hi, drop: int | None = None):
    """A collider's outline in a 2D picture: ('circle', (cx, cy), r) | ('rect', (x0, y0), (x1, y1)) |
    ('polygon', pts) | None.  drop: the axis projected away (3D scenes seen from the side), else 2D."""
    t = col.get("type")
    keep = [0, 1] if drop is None else [i for i in range(3) if i != drop]
    try:
        if t == "Sphere":
            c = np.asarray(col["center"], float)
            return ("circle", tuple(c[keep]), float(col["radius"]))
        if t == "Box":
            a, b = np.asarray(col["lower"], float), np.asarray(col["upper"], float)
            return ("rect", tuple(a[keep]), tuple(b[keep]))
        if t == "Cylinder":
            c, r, h = np.asarray(col["center"], float), float(col["radius"]), float(col["height"])
            ax = _AX.get(col.get("axis", "z"), 2)
            if drop is None and ax == 2 or ax == drop:
                return ("circle", tuple(c[keep]), r)
            half = np.full(len(c), r)
            half[ax] = h / 2
            return ("rect", tuple((c - half)[keep]), tuple((c + half)[keep]))
        if t == "Plane":
            p, n = np.asarray(col["point"], float), np.asarray(col["normal"], float)
            if drop is not None:
                if abs(n[drop]) > 1e-9:
                    return None
            p, n = p[keep], n[keep]
            lo2, hi2 = np.asarray(lo, float)[keep], np.asarray(hi, float)[keep]
            # solid side: the half of the domain rectangle behind the plane
            corners = np.array([[lo2[0], lo2[1]], [hi2[0], lo2[1]], [hi2[0], hi2[1]], [lo2[0], hi2[1]]])
            d = (corners - p) @ n
            poly = []
            for i in range(4):
                j = (i + 1) % 4
                if d[i] <= 0:
                    poly.append(corners[i])
                if d[i] * d[j] < 0:
                    poly.append(corners[i] + d[i] / (d[i] - d[j]) * (corners[j] - corners[i]))
            return ("polygon", np.asarray(poly)) if len(poly) >= 3 else None
    except (KeyError, TypeError, ValueError, IndexError):
        pass
    return None
