"""2D Mesh rigid bodies: a closed polygon (the body's outline in the x-y plane) and its signed-distance grid
(no Taichi).

File: a Wavefront OBJ whose ``v`` lines give the vertices (x y, a z if present must be 0) and either one
``f`` line (the polygon, its vertices in order) or ``l`` lines chaining the vertices into one closed loop;
other formats through meshio with one ``polygon``/``triangle``/``quad`` cell or ``line`` cells forming one
loop. The morph's ``scale`` (scalar or per axis, x and y used), ``rotate`` (the z angle [deg]; x and y must
be 0) and ``translate`` (x, y; a z must be 0) are applied in that order, as for a 3D Mesh morph. The
outline must be simple (:func:`self_contact`): an edge that crosses or touches another than its neighbours,
a vertex given twice or a spike of no width is refused with the two edges' file vertices.

Mass properties (:func:`polygon_mass_properties`): the exact area, centroid and polar moment of the
polygon by the shoelace sums (Green's theorem; e.g. Bourke, "Calculating the area and centroid of a
polygon", 1988): A = 1/2 sum c_i, c_i = x_i y_{i+1} - x_{i+1} y_i, C = 1/(6A) sum (p_i + p_{i+1}) c_i,
J_origin = 1/12 sum c_i (|p_i|^2 + p_i . p_{i+1} + |p_{i+1}|^2), about the centroid J_origin - A |C|^2.

Signed distance (:class:`PolygonSDF`): a node grid of cell ``h`` over the bounding box plus
``MARGIN_CELLS`` cells; |phi| the exact distance to the nearest edge, negative inside (even-odd crossing
test); sampled bilinearly (simcli.collider_mesh_kernels.MeshSDFField in 2D on the kernel side), FAR
outside the grid. ``triangles`` holds the outline's segments (k, 2): what a 2D collider's VTK cells and
sim.h5's ``surface_triangles`` are in 2D.
"""

from __future__ import annotations

import functools
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from simcli.collider_mesh import MARGIN_CELLS, GridSDF

MAX_NODES_2D = 4000**2


class PolygonError(ValueError):
    pass


def _read_obj(path: Path) -> tuple[np.ndarray, list[int]]:
    verts, face, lines = [], None, []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            tok = line.split()
            if not tok:
                continue
            if tok[0] == "v":
                verts.append([float(c) for c in tok[1:4]])
            elif tok[0] in ("f", "l"):
                idx = []
                for t in tok[1:]:
                    try:
                        i = int(t.split("/")[0])
                    except ValueError:
                        raise PolygonError(
                            f"'{path.name}': '{t}' in an {tok[0]} line is not a vertex index"
                        ) from None
                    k = i - 1 if i > 0 else len(verts) + i
                    if i == 0 or not 0 <= k < len(verts):
                        raise PolygonError(
                            f"'{path.name}': vertex index {i} in an {tok[0]} line is out of range "
                            f"(1..{len(verts)} or -1..-{len(verts)} for the {len(verts)} v lines before it)"
                        )
                    idx.append(k)
                if tok[0] == "f":
                    if face is not None:
                        raise PolygonError(
                            f"'{path.name}' has more than one face: a 2D Mesh body is one polygon in the x-y "
                            "plane (one f line, or l lines closing a loop); a closed 3D surface needs dim 3"
                        )
                    face = idx
                else:
                    lines += list(zip(idx[:-1], idx[1:]))
    V = np.zeros((len(verts), 3))
    for i, v in enumerate(verts):
        V[i, : len(v)] = v
    if face is not None:
        return V, face
    return V, _loop(lines, path.name)


def _loop(edges: list, name: str) -> list[int]:
    """The vertex order of segments that form one closed loop."""
    if len(edges) < 3:
        raise PolygonError(f"'{name}' has no polygon: give one f line or l lines that close a loop")
    nxt: dict[int, list[int]] = {}
    for a, b in edges:
        nxt.setdefault(a, []).append(b)
        nxt.setdefault(b, []).append(a)
    if any(len(v) != 2 for v in nxt.values()):
        raise PolygonError(
            f"'{name}': its segments do not form one closed loop (a vertex not on exactly two)"
        )
    start = edges[0][0]
    order, prev, cur = [start], None, start
    while True:
        a, b = nxt[cur]
        n = b if a == prev else a
        if n == start:
            break
        order.append(n)
        prev, cur = cur, n
    if len(order) != len(nxt):
        raise PolygonError(f"'{name}': its segments form more than one loop: give one closed outline")
    return order


def read_polygon(path: Path) -> np.ndarray:
    """The polygon's vertices (n, 3) in order, from an OBJ file or any file meshio reads."""
    V, order = read_polygon_indexed(path)
    return V[order]


def read_polygon_indexed(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(every vertex of the file (m, 3), the polygon's vertex indices in order (n,)): the indices name the
    file's vertices in messages (an OBJ's v lines from 1, meshio's points from 0)."""
    if path.suffix.lower() == ".obj":
        V, order = _read_obj(path)
    else:
        import meshio

        try:
            m = meshio.read(path)
        except Exception as ex:  # meshio raises many types
            raise PolygonError(f"cannot read '{path.name}': {ex}") from None
        V = np.zeros((len(m.points), 3))
        V[:, : m.points.shape[1]] = m.points
        polys = [c.data for c in m.cells if c.type.startswith(("polygon", "triangle", "quad"))]
        segs = [c.data for c in m.cells if c.type == "line"]
        if len(polys) == 1 and len(polys[0]) == 1:
            order = [int(i) for i in polys[0][0]]
        elif segs:
            order = _loop([tuple(int(i) for i in s) for s in np.concatenate(segs)], path.name)
        else:
            raise PolygonError(f"'{path.name}' holds no single polygon or closed loop of line segments")
    if len(order) < 3:
        raise PolygonError(f"'{path.name}': a polygon needs at least 3 vertices")
    if np.any(np.abs(V[:, 2]) > 1e-12 * max(1.0, float(np.abs(V).max()))):
        raise PolygonError(f"'{path.name}': a 2D outline lies in the x-y plane (its z must be 0)")
    return V, np.asarray(order, dtype=np.int64)


def transform_polygon(V: np.ndarray, scale, rotate, translate) -> np.ndarray:
    """(n, 2) points: scaled, turned about z by rotate[-1] degrees (rotate: 1 or 3 angles), translated."""
    s = np.ones(2) * float(scale) if np.isscalar(scale) else np.asarray(scale, float)[:2]
    x = np.asarray(V, float)[:, :2] * s
    a = math.radians(float(list(rotate)[-1])) if len(rotate) else 0.0
    c, si = math.cos(a), math.sin(a)
    x = x @ np.array([[c, si], [-si, c]])
    t = np.zeros(2)
    tt = list(translate)[:2]
    t[: len(tt)] = tt
    return x + t


def signed_area(P: np.ndarray) -> float:
    x, y = P[:, 0], P[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


TOUCH_TOL = 1e-9  # edges closer than this fraction of the polygon's extent touch


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
    return np.sqrt(((a + t[..., None] * ab - p) ** 2).sum(-1))


def self_contact(P: np.ndarray) -> tuple[str, int, int] | None:
    """The first place where the closed polygon P (n, 2) meets itself, or None for a simple polygon:
    ("short", i, i) an edge i (P[i] -> P[i+1]) of no length (its two vertices coincide); ("fold", i, i+1)
    two neighbouring edges that run back over each other; ("cross", i, j) or ("touch", i, j) two edges
    that are not neighbours and cross, or touch (a vertex on the other edge, or two coinciding vertices).
    Touching: closer than TOUCH_TOL times the polygon's extent. O(n^2) (outlines are small). A polygon
    that meets itself has no well-defined inside: the shoelace area, centroid and moment count a part
    twice or negatively."""
    P = np.asarray(P, float)
    n = len(P)
    A, B = P, np.roll(P, -1, axis=0)
    tol = TOUCH_TOL * max(float(np.max(P.max(axis=0) - P.min(axis=0))), 1e-300)
    short = np.nonzero(np.sqrt(((B - A) ** 2).sum(1)) <= tol)[0]
    if len(short):
        return ("short", int(short[0]), int(short[0]))
    # neighbours i, i+1 share B[i]; they overlap iff the far end of one lies on the other
    C = np.roll(B, -1, axis=0)
    fold = (_point_segment_distance(C, A, B) <= tol) | (_point_segment_distance(A, B, C) <= tol)
    if np.any(fold):
        i = int(np.nonzero(fold)[0][0])
        return ("fold", i, (i + 1) % n)

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (
            r[..., 0] - p[..., 0]
        )

    for i in range(n):
        j = np.arange(i + 2, n)
        if i == 0:
            j = j[j != n - 1]
        if not len(j):
            continue
        a, b, c, d = A[i], B[i], A[j], B[j]
        cross = (orient(a, b, c) * orient(a, b, d) < 0) & (orient(c, d, a[None]) * orient(c, d, b[None]) < 0)
        gap = np.minimum(
            np.minimum(_point_segment_distance(a[None], c, d), _point_segment_distance(b[None], c, d)),
            np.minimum(
                _point_segment_distance(c, a[None], b[None]), _point_segment_distance(d, a[None], b[None])
            ),
        )
        hit = np.nonzero(cross | (gap <= tol))[0]
        if len(hit):
            return ("cross" if cross[hit[0]] else "touch", i, int(j[hit[0]]))
    return None


def simple(P: np.ndarray) -> bool:
    """No edge of the closed polygon P meets another except its two neighbours at their shared vertices."""
    return self_contact(P) is None


def self_contact_message(name: str, V: np.ndarray, order: np.ndarray, P: np.ndarray, obj: bool) -> str | None:
    """The scene error for a polygon P (placed, (n, 2)) that meets itself (``self_contact``), or None for a
    simple one. It names the file's vertices with their coordinates in the file: ``V`` the file's vertices,
    ``order`` the file's index of each vertex of P; ``obj``: OBJ v lines numbered from 1, else meshio's
    points from 0."""
    found = self_contact(P)
    if found is None:
        return None
    kind, i, j = found
    n = len(P)
    base, word = (1, "v line") if obj else (0, "point")

    def vert(k: int) -> str:
        x, y = V[order[k % n], :2]
        return f"{word} {int(order[k % n]) + base} ({x:.6g}, {y:.6g})"

    def edge(k: int) -> str:
        return f"the edge from {vert(k)} to {vert(k + 1)}"

    if kind == "short":
        return (
            f"'{name}': the polygon meets itself: {vert(i)} and {vert(i + 1)} coincide ({edge(i)} has no "
            "length): remove one of them from the outline"
        )
    if kind == "fold":
        return (
            f"'{name}': the polygon meets itself: {edge(i)} and {edge(j)} run back over each other (a "
            f"spike of no width at {vert(j)}): remove {vert(j)} or move it off the line"
        )
    verb = "crosses" if kind == "cross" else "touches"
    how = "cross" if kind == "cross" else "touch (a vertex on the other edge, or two vertices at one point)"
    return (
        f"'{name}': the polygon {verb} itself: {edge(i)} and {edge(j)} {how}; give a simple closed "
        "outline (each edge meets only its two neighbours, at their shared vertices): move or reorder those "
        "vertices, or split the outline into separate bodies"
    )


def polygon_mass_properties(P: np.ndarray, rho: float) -> tuple[float, np.ndarray, float]:
    """(mass per metre of depth [kg/m], centroid (2,), polar moment about it [kg m^2 / m]) of the
    counter-clockwise polygon P (n, 2) at density rho (shoelace sums, module docstring)."""
    P = np.asarray(P, float)
    Q = np.roll(P, -1, axis=0)
    c = P[:, 0] * Q[:, 1] - Q[:, 0] * P[:, 1]
    A = 0.5 * float(c.sum())
    if not A > 0:
        raise PolygonError(f"the polygon encloses no positive area ({A:.3g} m^2)")
    C = ((P + Q) * c[:, None]).sum(axis=0) / (6.0 * A)
    J0 = float(np.sum(c * ((P * P).sum(1) + (P * Q).sum(1) + (Q * Q).sum(1)))) / 12.0
    return rho * A, C, rho * (J0 - A * float(C @ C))


class PolygonSDF(GridSDF):
    """A closed polygon (body frame = its placement at t = 0) and its signed-distance grid (2D; shape,
    bounds, sample and normal: simcli.collider_mesh.GridSDF's, as a 3D Mesh's)."""

    def __init__(self, P: np.ndarray, h: float, source: str) -> None:
        t0 = time.perf_counter()
        self.vertices = np.asarray(P, float)  # (n, 2), counter-clockwise
        n = len(P)
        self.triangles = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)  # the outline's segments
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        h = float(h)
        while np.prod(np.ceil((hi - lo) / h) + 2 * MARGIN_CELLS + 1) > MAX_NODES_2D:
            h *= 1.5
        self.h = h
        self.origin = lo - MARGIN_CELLS * h
        shape = tuple(int(v) for v in np.ceil((hi - lo) / h) + 2 * MARGIN_CELLS + 1)
        g = np.stack(
            np.meshgrid(*[self.origin[a] + h * np.arange(shape[a]) for a in range(2)], indexing="ij"), -1
        )
        self.phi = signed_distance(self.vertices, g.reshape(-1, 2)).reshape(shape)
        self.source = source
        self.volume = signed_area(self.vertices)
        self.build_seconds = time.perf_counter() - t0


def signed_distance(P: np.ndarray, x: np.ndarray, chunk: int = 1 << 21) -> np.ndarray:
    """Exact signed distance from points x (k, 2) to the closed polygon P (n, 2): negative inside."""
    A, B = P, np.roll(P, -1, axis=0)
    AB = B - A
    L2 = np.maximum((AB * AB).sum(1), 1e-300)
    out = np.empty(len(x))
    step = max(1, chunk // len(P))
    for s in range(0, len(x), step):
        q = x[s : s + step, None, :]
        t = np.clip(((q - A) * AB).sum(-1) / L2, 0.0, 1.0)
        d = np.sqrt((((A + t[..., None] * AB) - q) ** 2).sum(-1)).min(axis=1)
        # even-odd crossings of a ray towards +x
        y = q[..., 1]
        cond = (A[:, 1] > y) != (B[:, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = A[:, 0] + (y - A[:, 1]) * AB[:, 0] / np.where(AB[:, 1] != 0, AB[:, 1], 1.0)
        inside = (np.sum(cond & (q[..., 0] < xc), axis=1) % 2) == 1
        out[s : s + step] = np.where(inside, -d, d)
    return out


@functools.lru_cache(maxsize=16)
def _build_cached(path: str, mtime: int, size: int, scale, rotate: tuple, translate: tuple, h: float):
    V, order = read_polygon_indexed(Path(path))
    P = transform_polygon(V[order], scale, rotate, translate)
    msg = self_contact_message(Path(path).name, V, order, P, Path(path).suffix.lower() == ".obj")
    if msg is not None:
        raise PolygonError(msg)
    if abs(signed_area(P)) <= 0:
        raise PolygonError(f"'{Path(path).name}': the polygon encloses no area")
    if signed_area(P) < 0:  # counter-clockwise: outward normals to the right of each edge
        P = P[::-1].copy()
    return PolygonSDF(P, h, path)


def build_polygon_sdf(rb: Any, scene: Any = None, scene_dir: Any = None) -> PolygonSDF:
    """The PolygonSDF of a 2D Mesh rigid body (cached per file, transform and cell); cell: ``sdf_cell`` or
    half the finest length of the families present (as a Mesh collider's)."""
    from simcli.collider_mesh import default_cell
    from simcli.geometry.mesh import MeshFileNotFoundError, resolve_mesh_path

    m = rb.morph
    path = resolve_mesh_path(m.file, scene_dir)
    try:
        st = path.stat()
    except OSError:
        raise MeshFileNotFoundError(
            f"mesh file not found: '{m.file}' (looked for '{path}'; relative paths are relative to the "
            "scene file's folder)"
        ) from None
    scale = m.scale if isinstance(m.scale, (int, float)) else tuple(float(v) for v in m.scale)
    h = getattr(rb, "sdf_cell", None) or (default_cell(scene) if scene is not None else None)
    if h is None:
        P = transform_polygon(read_polygon(path), scale, m.rotate, m.translate)
        h = float(np.max(P.max(axis=0) - P.min(axis=0))) / 64.0
    return _build_cached(
        str(path.resolve()),
        st.st_mtime_ns,
        st.st_size,
        scale,
        tuple(float(v) for v in m.rotate),
        tuple(float(v) for v in m.translate),
        float(h),
    )
