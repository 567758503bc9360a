"""Surface meshes for `Mesh` morphs: loading, transform, closedness check, inside test.

Plain numpy + meshio, no Taichi.

Loading (``read_surface``)
    Any format meshio reads (.obj, .stl, .ply, .off, .vtk/.vtu, .msh, ...).
    Triangles are used as they are, quads and polygons are split into triangles
    (fan, so polygons are assumed convex); quadratic cells use their corner nodes.
    A volume mesh (tetrahedra) is reduced to its boundary surface. Exact duplicate
    vertices are merged (STL files store each triangle's corners separately) and
    triangles that collapse are dropped.

Closedness (``check_closed``)
    The fill needs a watertight surface: every edge must be shared by exactly two
    triangles that traverse it in opposite directions (consistent orientation).
    Otherwise a ``MeshError`` names the file and counts boundary edges, non-manifold
    edges and inconsistently oriented edges. An inside-out surface (every normal
    pointing inwards) is accepted and flipped. Self-intersections are *not* checked.

Transform (``transform_points``), in this order:
    1. scale: a scalar or one factor per axis, about the file's origin;
    2. rotate: Euler angles [deg] (rx, ry, rz) about the *fixed* (world) axes,
       first about x, then about y, then about z ("extrinsic xyz"), i.e.
       ``R = Rz(rz) @ Ry(ry) @ Rx(rx)``, about the origin; this is the same as
       ``scipy.spatial.transform.Rotation.from_euler("xyz", [rx, ry, rz], degrees=True)``
       and as Genesis's ``euler`` option;
    3. translate [m].

Inside test (``lattice_inside_mesh``, ``points_inside_mesh``)
    Ray parity with rays along +x. For a lattice, each lattice row (y_j, z_k) is one
    ray: every triangle is intersected only with the rays that pass through its
    yz bounding box, and a running sum of the crossings along each ray gives the
    parity of every lattice point on it, so the cost is
    O(triangles x rays per triangle + lattice points). Rays that hit an edge or a
    vertex exactly (common: lattice points are symmetric, so they often lie on the
    diagonals of a cube's faces) are decided by a consistent tie-break rule
    (simulation of simplicity: the point is nudged by (e, e^2) in (y, z)), and each
    edge's orientation test is evaluated from its lower-numbered vertex, so the two
    triangles sharing an edge always agree and the crossing is counted exactly once.

Thin parts
    A lattice point is kept if it lies inside the surface. A part of the mesh thinner
    than the particle spacing may fall between lattice points and get no particles;
    ``lattice_inside_mesh`` measures the volume of the ray intervals inside the mesh
    that contain no lattice point (``InsideResult.missed_volume``) and returns their
    midpoints (``InsideResult.thin_points``): rays along x, y and z, so a thin sheet in any
    orientation is found by the rays across it, and the sampler places one layer of
    particles there (an ear, a fin, a claw). The total mass stays exact: the body's mass is
    spread over the particles that were placed.
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "InsideResult",
    "MeshError",
    "MeshFileNotFoundError",
    "TriMesh",
    "check_closed",
    "lattice_inside_mesh",
    "load_mesh_morph",
    "mesh_bounds",
    "points_inside_mesh",
    "read_surface",
    "resolve_mesh_path",
    "rotation_matrix",
    "signed_volume",
    "transform_points",
]


class MeshError(ValueError):
    """A mesh file that cannot be used: unreadable, not closed, empty, zero volume..."""


class MeshFileNotFoundError(MeshError, FileNotFoundError):
    """The mesh file does not exist (both a MeshError and a FileNotFoundError)."""


@dataclass(frozen=True)
class TriMesh:
    """A closed, outward-oriented triangle surface in world coordinates."""

    vertices: np.ndarray  # (n, 3) float64
    triangles: np.ndarray  # (m, 3) int64, outward (counter-clockwise seen from outside)
    volume: float  # enclosed volume [m^3], > 0
    source: str = ""  # file it came from (for messages)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)


@dataclass
class InsideResult:
    """Result of the lattice inside test."""

    inside: np.ndarray  # bool (nx, ny, nz)
    missed_volume: float = 0.0  # volume of inside ray intervals that hold no lattice point [m^3]
    odd_rays: int = 0  # rays with an odd number of crossings (should be 0 for a closed mesh)
    warnings: list[str] = field(default_factory=list)
    # midpoints (m, 3) of the inside ray intervals that hold no lattice point (thin parts), world frame
    thin_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


# ------------------------------------------------------------------------ loading


def resolve_mesh_path(file: str | os.PathLike, scene_dir: str | os.PathLike | None = None) -> Path:
    """The mesh file's path: absolute as given, else relative to the scene file's folder."""
    p = Path(os.path.expanduser(str(file)))
    if not p.is_absolute():
        p = Path(scene_dir if scene_dir is not None else ".") / p
    return p


def _triangles_from_cells(mesh, name: str) -> np.ndarray:
    surface: list[np.ndarray] = []
    volume: list[np.ndarray] = []
    for block in mesh.cells:
        ctype = block.type
        data = np.asarray(block.data, dtype=np.int64)
        if data.size == 0:
            continue
        if ctype in ("triangle", "triangle6", "triangle7"):
            surface.append(data[:, :3])
        elif ctype in ("quad", "quad8", "quad9"):
            q = data[:, :4]
            surface.append(np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))
        elif ctype.startswith("polygon"):
            k = data.shape[1]
            fan = [data[:, [0, i, i + 1]] for i in range(1, k - 1)]
            if fan:
                surface.append(np.concatenate(fan))
        elif ctype in ("tetra", "tetra10"):
            volume.append(data[:, :4])
        elif ctype in ("vertex", "line", "line3"):
            continue
        else:
            raise MeshError(
                f"mesh '{name}': cell type '{ctype}' is not supported for filling "
                "(use triangles, quads, polygons or tetrahedra)"
            )
    if volume:
        return _tet_boundary(np.concatenate(volume), np.asarray(mesh.points, dtype=np.float64))
    if not surface:
        raise MeshError(f"mesh '{name}' has no triangles, quads, polygons or tetrahedra")
    return np.concatenate(surface)


def _tet_boundary(tets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Outward boundary triangles of a tetrahedral mesh (faces used by one tetrahedron)."""
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    opposite = np.concatenate([tets[:, 0], tets[:, 1], tets[:, 2], tets[:, 3]])
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    keep = counts[inv] == 1
    faces, opposite = faces[keep], opposite[keep]
    a, b, c = points[faces[:, 0], :3], points[faces[:, 1], :3], points[faces[:, 2], :3]
    d = points[opposite, :3]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) > 0
    faces[inward] = faces[inward][:, [0, 2, 1]]
    return faces


def _clean(points: np.ndarray, tris: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    if points.ndim != 2 or points.shape[0] == 0:
        raise MeshError(f"mesh '{name}' has no points")
    if points.shape[1] == 2:
        points = np.concatenate([points, np.zeros((points.shape[0], 1))], axis=1)
    points = points[:, :3]
    if tris.size and (tris.min() < 0 or tris.max() >= points.shape[0]):
        raise MeshError(f"mesh '{name}': a face refers to a vertex that does not exist")
    # keep only referenced vertices, merge exact duplicates
    used, inv = np.unique(tris.reshape(-1), return_inverse=True)
    pts = points[used]
    if not np.all(np.isfinite(pts)):
        raise MeshError(f"mesh '{name}' has non-finite vertex coordinates")
    merged, inv2 = np.unique(pts, axis=0, return_inverse=True)
    tris = inv2.reshape(-1)[inv.reshape(-1)].reshape(-1, 3)
    ok = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 2] != tris[:, 0])
    tris = tris[ok]
    if tris.shape[0] == 0:
        raise MeshError(f"mesh '{name}' has no non-degenerate triangles")
    # drop vertices that only degenerate triangles used
    used, inv = np.unique(tris.reshape(-1), return_inverse=True)
    return np.ascontiguousarray(merged[used]), inv.reshape(-1, 3).astype(np.int64)


def _read_obj(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a Wavefront OBJ file: ``v`` and ``f`` lines only (``f`` entries
    ``i``, ``i/t``, ``i//n`` or ``i/t/n``, negative indices relative, polygons split in fans).
    meshio refuses common real-world OBJ files (texture coordinates counted per corner, not per
    vertex; several objects or groups): their geometry is all a fill needs."""
    verts: list[list[float]] = []
    tris: list[tuple[int, int, int]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.startswith("v "):
                verts.append([float(c) for c in line.split()[1:4]])
            elif line.startswith("f "):
                idx = []
                for tok in line.split()[1:]:
                    k = int(tok.split("/")[0])
                    idx.append(k - 1 if k > 0 else len(verts) + k)
                tris += [(idx[0], idx[i], idx[i + 1]) for i in range(1, len(idx) - 1)]
    if not verts or not tris:
        raise MeshError(f"mesh '{path}' has no vertices or faces")
    return np.asarray(verts, dtype=np.float64), np.asarray(tris, dtype=np.int64)


def _drop_duplicate_faces(tris: np.ndarray) -> np.ndarray:
    """Remove repeated triangles (the same three vertices, either orientation): real meshes often
    carry them (a face exported twice; a zero-volume double-sided fin). A pair of opposite copies
    encloses nothing and is dropped entirely; a repeated copy is kept once."""
    key = np.sort(tris, axis=1)
    _, first, inv, counts = np.unique(key, axis=0, return_index=True, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    if np.all(counts == 1):
        return tris
    # orientation sign of each copy relative to its sorted key (even permutation: +1)
    par = np.where(
        (tris[:, 0] == key[:, 0]) & (tris[:, 1] == key[:, 1])
        | (tris[:, 1] == key[:, 0]) & (tris[:, 2] == key[:, 1])
        | (tris[:, 2] == key[:, 0]) & (tris[:, 0] == key[:, 1]),
        1,
        -1,
    )
    net = np.bincount(inv, weights=par, minlength=counts.size)
    keep = np.zeros(len(tris), bool)
    keep[first] = True
    keep &= net[inv] != 0  # opposite copies cancel
    return tris[keep]


@functools.lru_cache(maxsize=16)
def _read_cached(path: str, mtime_ns: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    import meshio

    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")  # e.g. meshio's binary-STL size probe on ASCII files
            mesh = meshio.read(path)
        tris = _triangles_from_cells(mesh, path)
        points = np.asarray(mesh.points, dtype=np.float64)
    except Exception as exc:  # meshio raises many types (ReadError, ValueError, KeyError...)
        if not path.lower().endswith(".obj"):
            raise MeshError(f"cannot read mesh '{path}': {exc}") from exc
        points, tris = _read_obj(path)
    pts, tris = _clean(points, tris, path)
    tris = _drop_duplicate_faces(tris)
    check_closed(tris, path)
    pts.flags.writeable = False
    tris.flags.writeable = False
    return pts, tris


def read_surface(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a closed surface: (vertices (n, 3) float64, triangles (m, 3) int64), untransformed.

    Raises ``MeshFileNotFoundError`` if the file does not exist and ``MeshError`` if it
    cannot be read or is not a closed surface. Results are cached per (path, mtime, size);
    the returned arrays are read-only.
    """
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise MeshFileNotFoundError(f"mesh file not found: '{p}'") from None
    if not p.is_file():
        raise MeshError(f"mesh path is not a file: '{p}'")
    return _read_cached(str(p.resolve()), st.st_mtime_ns, st.st_size)


def check_closed(triangles: np.ndarray, name: str = "mesh") -> None:
    """Raise MeshError unless every edge is shared by exactly two oppositely oriented triangles."""
    t = np.asarray(triangles, dtype=np.int64)
    a = np.concatenate([t[:, 0], t[:, 1], t[:, 2]])
    b = np.concatenate([t[:, 1], t[:, 2], t[:, 0]])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * (int(t.max()) + 1) + hi
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    forward = np.bincount(inv, weights=(a < b).astype(np.float64), minlength=counts.size)
    n_boundary = int(np.count_nonzero(counts == 1))
    n_nonmanifold = int(np.count_nonzero(counts > 2))
    n_flipped = int(np.count_nonzero((counts == 2) & (forward != 1)))
    if n_boundary or n_nonmanifold or n_flipped:
        problems = []
        if n_boundary:
            problems.append(
                f"{n_boundary} boundary edge(s) (used by only one triangle: the surface has holes)"
            )
        if n_nonmanifold:
            problems.append(f"{n_nonmanifold} non-manifold edge(s) (shared by more than two triangles)")
        if n_flipped:
            problems.append(
                f"{n_flipped} edge(s) between triangles of opposite orientation (inconsistent normals)"
            )
        raise MeshError(
            f"mesh '{name}' is not a closed surface: "
            + "; ".join(problems)
            + ". Filling a mesh with particles needs a closed (watertight), consistently oriented "
            "surface: repair it (e.g. MeshLab, Blender 3D-Print toolbox) or use a tetrahedral mesh."
        )


# ---------------------------------------------------------------------- transform


def rotation_matrix(euler_deg: Sequence[float]) -> np.ndarray:
    """R = Rz @ Ry @ Rx for Euler angles (rx, ry, rz) in degrees, extrinsic x, then y, then z."""
    if len(euler_deg) != 3:
        raise ValueError(f"rotate needs 3 Euler angles [deg] (x, y, z), got {list(euler_deg)}")
    rx, ry, rz = (math.radians(float(v)) for v in euler_deg)
    cx, sx, cy, sy, cz, sz = (
        math.cos(rx),
        math.sin(rx),
        math.cos(ry),
        math.sin(ry),
        math.cos(rz),
        math.sin(rz),
    )
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    Rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def _scale_vector(scale) -> np.ndarray:
    if isinstance(scale, (int, float)):
        s = np.full(3, float(scale))
    else:
        s = np.asarray(scale, dtype=np.float64).reshape(-1)
        if s.size == 1:
            s = np.full(3, float(s[0]))
        elif s.size != 3:
            raise ValueError(f"scale must be a number or 3 factors (x, y, z), got {list(scale)}")
    if not np.all(np.isfinite(s)) or np.any(s == 0):
        raise ValueError(f"scale factors must be finite and non-zero, got {s.tolist()}")
    return s


def transform_points(
    points: np.ndarray, scale=1.0, rotate=(0.0, 0.0, 0.0), translate=(0.0, 0.0, 0.0)
) -> np.ndarray:
    """Scale, then rotate (extrinsic x, y, z Euler angles in degrees), then translate."""
    t = np.asarray(translate, dtype=np.float64).reshape(-1)
    if t.size != 3:
        raise ValueError(f"translate must have 3 components (x, y, z), got {list(translate)}")
    x = np.asarray(points, dtype=np.float64) * _scale_vector(scale)
    return x @ rotation_matrix(rotate).T + t


def signed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Enclosed volume by the divergence theorem (positive for outward-oriented triangles)."""
    v = np.asarray(vertices, dtype=np.float64)
    # relative to the centroid, for accuracy far from the origin
    v = v - v.mean(axis=0)
    a, b, c = v[triangles[:, 0]], v[triangles[:, 1]], v[triangles[:, 2]]
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def load_mesh_morph(morph, scene_dir: str | os.PathLike | None = None) -> TriMesh:
    """Read, check and transform a `Mesh` morph: a closed, outward-oriented TriMesh in world space."""
    path = resolve_mesh_path(morph.file, scene_dir)
    try:
        verts, tris = read_surface(path)
    except MeshFileNotFoundError:
        raise MeshFileNotFoundError(
            f"mesh file not found: '{morph.file}' (looked for '{path}'; relative paths are relative "
            "to the scene file's folder)"
        ) from None
    try:
        x = transform_points(verts, morph.scale, morph.rotate, morph.translate)
    except ValueError as exc:
        raise MeshError(f"mesh '{morph.file}': {exc}") from None
    vol = signed_volume(x, tris)
    extent = float(np.max(x.max(axis=0) - x.min(axis=0)))
    if not abs(vol) > 1e-12 * extent**3:
        raise MeshError(f"mesh '{morph.file}' encloses no volume (signed volume {vol:.3g} m^3)")
    if vol < 0:  # inside-out (or mirrored by a negative scale): flip every triangle
        tris = tris[:, [0, 2, 1]]
        vol = -vol
    x.flags.writeable = False
    return TriMesh(vertices=x, triangles=np.ascontiguousarray(tris), volume=vol, source=str(path))


def mesh_bounds(morph, scene_dir: str | os.PathLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners [m] of the transformed mesh's axis-aligned bounding box."""
    return load_mesh_morph(morph, scene_dir).bounds


# ---------------------------------------------------------------------- inside test


class _Edges:
    """Per-triangle data for the robust 2D point-in-triangle test in the (y, z) plane.

    Stored as rows of one (28, m) array so that a pair list gathers it in one pass:
    per edge e (0..2) rows 6e..6e+5: Pu, Pw (canonical start), du, dw (canonical
    direction), s (+1 if the triangle runs along the canonical direction, else -1),
    zs (the sign to use when the edge function is exactly 0); rows 18..23: vertex A
    and the normal n = (B - A) x (C - A); rows 24..27: yz bounding box.
    """

    def __init__(self, V: np.ndarray, T: np.ndarray):
        yz = V[:, 1:3]
        m = T.shape[0]
        D = np.empty((28, m))
        for e, (i0, i1) in enumerate(((0, 1), (1, 2), (2, 0))):
            a, b = T[:, i0], T[:, i1]
            fwd = a < b
            p = np.where(fwd, a, b)  # canonical: from the lower-numbered vertex
            q = np.where(fwd, b, a)
            du = yz[q, 0] - yz[p, 0]
            dw = yz[q, 1] - yz[p, 1]
            s = np.where(fwd, 1.0, -1.0)
            D[6 * e + 0] = yz[p, 0]
            D[6 * e + 1] = yz[p, 1]
            D[6 * e + 2] = du
            D[6 * e + 3] = dw
            D[6 * e + 4] = s
            # the edge function is exactly 0: decide as if the point were nudged by (eps, eps^2)
            D[6 * e + 5] = s * np.where(dw != 0, -np.sign(dw), np.sign(du))
        A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
        D[18:21] = A.T
        n = np.cross(B - A, C - A)  # n[:, 0] = twice the projected (yz) area
        D[21:24] = n.T
        tyz = V[T][:, :, 1:3]
        D[24] = tyz[:, :, 0].min(axis=1)
        D[25] = tyz[:, :, 0].max(axis=1)
        D[26] = tyz[:, :, 1].min(axis=1)
        D[27] = tyz[:, :, 1].max(axis=1)
        self.D = D
        self.crossable = n[:, 0] != 0  # triangles parallel to the rays are never crossed

    @property
    def bbox(self):
        return self.D[24], self.D[25], self.D[26], self.D[27]

    def crossings(
        self, tri: np.ndarray, pu: np.ndarray, pw: np.ndarray, cull: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """For pairs (triangle, point (y, z)): does the +x ray cross the triangle, and at which x.

        Returns (hit mask over the pairs, x of the crossing for the pairs hit).
        ``cull``: first drop the pairs whose point is outside the triangle's yz bounding box.
        """
        if cull:
            B = np.take(self.D[24:28], tri, axis=1)
            sel = np.nonzero((pu >= B[0]) & (pu <= B[1]) & (pw >= B[2]) & (pw <= B[3]))[0]
            hit = np.zeros(tri.shape[0], dtype=bool)
            h2, xc = self.crossings(tri[sel], pu[sel], pw[sel])
            hit[sel[h2]] = True
            return hit, xc
        D = np.take(self.D[:18], tri, axis=1)
        for e in range(3):
            r = D[6 * e : 6 * e + 6]
            v = r[4] * (r[2] * (pw - r[1]) - r[3] * (pu - r[0]))
            v = np.where(v != 0, v, r[5])
            if e == 0:
                pos, neg = v > 0, v < 0
            else:
                pos &= v > 0
                neg &= v < 0
        hit = pos | neg
        t = tri[hit]
        A = np.take(self.D[18:24], t, axis=1)
        xc = A[0] - (A[4] * (pu[hit] - A[1]) + A[5] * (pw[hit] - A[2])) / A[3]
        return hit, xc


def _bbox_ranges(lo: np.ndarray, hi: np.ndarray, origin: float, h: float, n: int, half_open_bins: bool):
    """Index range [i0, i1] of lattice coordinates origin + i h (or bins around them) inside [lo, hi]."""
    tol = 1e-7
    if half_open_bins:
        i0 = np.floor((lo - origin) / h + 0.5 - tol)
        i1 = np.floor((hi - origin) / h + 0.5 + tol)
    else:
        i0 = np.ceil((lo - origin) / h - tol)
        i1 = np.floor((hi - origin) / h + tol)
    return (
        np.clip(i0, 0, n - 1).astype(np.int64),
        np.clip(i1, -1, n - 1).astype(np.int64),
        (i1 >= 0) & (i0 <= n - 1),
    )


def _pair_chunks(counts: np.ndarray, max_pairs: int):
    """Split triangles into consecutive chunks holding at most ~max_pairs (triangle, ray) pairs."""
    csum = np.cumsum(counts)
    start = 0
    m = counts.size
    while start < m:
        base = csum[start - 1] if start else 0
        stop = int(np.searchsorted(csum, base + max_pairs, side="right"))
        stop = max(stop, start + 1)
        yield start, min(stop, m)
        start = stop


_MAX_PAIRS = 1 << 21


def _lattice_ray_crossings(V, T, origin, h, shape) -> tuple[np.ndarray, np.ndarray]:
    """Crossings of the +x rays through the lattice rows (y_j, z_k) with the surface.

    Returns (ray index j * nz + k, x of the crossing) for every crossing.
    """
    oy, oz = float(origin[1]), float(origin[2])
    ny, nz = int(shape[1]), int(shape[2])
    edges = _Edges(V, T)
    umin, umax, wmin, wmax = edges.bbox
    keep = edges.crossable
    j0, j1, okj = _bbox_ranges(umin, umax, oy, h, ny, False)
    k0, k1, okk = _bbox_ranges(wmin, wmax, oz, h, nz, False)
    nj = np.where(okj & keep, np.maximum(j1 - j0 + 1, 0), 0)
    nk = np.where(okk & keep, np.maximum(k1 - k0 + 1, 0), 0)
    counts = nj * nk

    ray_ids: list[np.ndarray] = [np.zeros(0, dtype=np.int64)]
    xcs: list[np.ndarray] = [np.zeros(0)]
    for a, b in _pair_chunks(counts, _MAX_PAIRS):
        c = counts[a:b]
        total = int(c.sum())
        if total == 0:
            continue
        tri = np.repeat(np.arange(a, b), c)
        off = np.arange(total) - np.repeat(np.cumsum(c) - c, c)
        nkt = nk[tri]
        j = j0[tri] + off // nkt
        k = k0[tri] + off % nkt
        hit, xc = edges.crossings(tri, oy + j * h, oz + k * h)
        ray_ids.append((j * nz + k)[hit])
        xcs.append(xc)
    return np.concatenate(ray_ids), np.concatenate(xcs)


def _missed_volume(ray: np.ndarray, first: np.ndarray, xc: np.ndarray, h: float) -> float:
    """Volume of the inside intervals of the rays that contain no lattice point (h^2 x length)."""
    if xc.size == 0 or np.any(np.bincount(ray) & 1):
        return 0.0
    order = np.lexsort((xc, ray))
    x_s, f_s = xc[order], first[order]
    empty = f_s[0::2] == f_s[1::2]
    return float(np.sum(x_s[1::2][empty] - x_s[0::2][empty])) * h * h


def _missed_midpoints(
    ray: np.ndarray, first: np.ndarray, xc: np.ndarray, origin, h: float, nz: int
) -> np.ndarray:
    """Midpoints (in the ray frame: x along the ray, then the lattice's y, z) of the inside intervals
    of the rays that hold no lattice point; none where a ray crosses the surface an odd number of times."""
    if xc.size == 0:
        return np.zeros((0, 3))
    odd = np.bincount(ray) & 1
    ok = odd[ray] == 0
    ray, first, xc = ray[ok], first[ok], xc[ok]
    if xc.size == 0:
        return np.zeros((0, 3))
    order = np.lexsort((xc, ray))
    x_s, f_s, r_s = xc[order], first[order], ray[order]
    empty = f_s[0::2] == f_s[1::2]
    r = r_s[0::2][empty]
    mid = 0.5 * (x_s[0::2][empty] + x_s[1::2][empty])
    return np.stack([mid, origin[1] + (r // nz) * h, origin[2] + (r % nz) * h], axis=1)


def lattice_inside_mesh(
    mesh: TriMesh,
    origin: Sequence[float],
    spacing: float,
    shape: Sequence[int],
    thin_check_axes: Sequence[int] = (0, 1, 2),
) -> InsideResult:
    """Which points origin + spacing * (i, j, k), 0 <= (i, j, k) < shape, lie inside the closed mesh.

    Returns an InsideResult whose ``inside`` is a bool array of the given shape. The
    inside test casts rays along x. ``missed_volume`` is the largest, over the axes in
    ``thin_check_axes``, of the volume of the inside intervals of the lattice rays along
    that axis that hold no lattice point: parts of the mesh thinner than the spacing
    along that axis that got no particles (casting rays along y and z costs about as
    much again each; pass ``()`` to skip the check).
    """
    origin = np.asarray(origin, dtype=np.float64)
    h = float(spacing)
    shape = tuple(int(v) for v in shape)
    nx, ny, nz = shape
    V, T = mesh.vertices, mesh.triangles

    ray, xc = _lattice_ray_crossings(V, T, origin, h, shape)
    # first lattice index strictly beyond each crossing
    first = np.clip(np.floor((xc - origin[0]) / h).astype(np.int64) + 1, 0, nx)
    hist = np.bincount(ray * (nx + 1) + first, minlength=ny * nz * (nx + 1)).reshape(ny, nz, nx + 1)
    left = np.cumsum(hist, axis=2)[:, :, :nx]  # crossings before each point
    total = left[:, :, -1:] + hist[:, :, nx:]  # all crossings of the ray
    inside = (left & 1).astype(bool)
    n_odd = int(np.count_nonzero(total[:, :, 0] & 1))
    if n_odd:  # should not happen on a closed mesh; be conservative: inside seen from both ends
        inside &= ((total - left) & 1).astype(bool)
    inside = np.ascontiguousarray(inside.transpose(2, 0, 1))

    missed = 0.0
    thin = [np.zeros((0, 3))]
    for axis in thin_check_axes:
        if axis == 0:
            missed = max(missed, _missed_volume(ray, first, xc, h))
            thin.append(_missed_midpoints(ray, first, xc, origin, h, nz))
            continue
        perm = [axis, (axis + 1) % 3, (axis + 2) % 3]  # cyclic: the ray axis becomes x
        r2, x2 = _lattice_ray_crossings(V[:, perm], T, origin[perm], h, [shape[p] for p in perm])
        f2 = np.clip(np.floor((x2 - origin[axis]) / h).astype(np.int64) + 1, 0, shape[axis])
        missed = max(missed, _missed_volume(r2, f2, x2, h))
        pts = _missed_midpoints(r2, f2, x2, origin[perm], h, shape[perm[2]])
        back = np.empty_like(pts)
        back[:, perm] = pts  # ray frame -> world frame
        thin.append(back)

    res = InsideResult(inside=inside, missed_volume=missed, odd_rays=n_odd, thin_points=np.concatenate(thin))
    if n_odd:
        res.warnings.append(
            f"mesh '{mesh.source}': {n_odd} ray(s) crossed the surface an odd number of times "
            "(self-intersecting or nearly degenerate surface?); points on them were classified conservatively"
        )
    return res


def points_inside_mesh(mesh: TriMesh, points: np.ndarray, bin_size: float | None = None) -> np.ndarray:
    """Which of the arbitrary points (n, 3) lie inside the closed mesh (ray parity along +x).

    Triangles are binned in the yz plane by their bounding box (bins of ``bin_size``,
    default: about the mean triangle size); each point is tested against the
    triangles of its bin only.
    """
    pts = np.asarray(points, dtype=np.float64)
    n = pts.shape[0]
    result = np.zeros(n, dtype=bool)
    if n == 0:
        return result
    V, T = mesh.vertices, mesh.triangles
    lo, hi = V.min(axis=0), V.max(axis=0)
    cand = np.all((pts >= lo) & (pts <= hi), axis=1)
    idx = np.nonzero(cand)[0]
    if idx.size == 0:
        return result
    p = pts[idx]
    edges = _Edges(V, T)
    keep = edges.crossable
    umin, umax, wmin, wmax = edges.bbox
    if bin_size is None:
        ext = np.maximum(umax - umin, wmax - wmin)
        bin_size = float(np.median(ext[keep])) if np.any(keep) else float(np.max(hi - lo))
        bin_size = max(bin_size, float(np.max(hi[1:] - lo[1:])) / 2048.0, 1e-12)
    h = float(bin_size)
    oy, oz = lo[1], lo[2]
    ny = int(np.floor((hi[1] - oy) / h)) + 2
    nz = int(np.floor((hi[2] - oz) / h)) + 2
    j0, j1, okj = _bbox_ranges(umin, umax, oy, h, ny, True)
    k0, k1, okk = _bbox_ranges(wmin, wmax, oz, h, nz, True)
    nj = np.where(okj & keep, np.maximum(j1 - j0 + 1, 0), 0)
    nk = np.where(okk & keep, np.maximum(k1 - k0 + 1, 0), 0)
    counts = nj * nk
    total = int(counts.sum())
    tri = np.repeat(np.arange(T.shape[0]), counts)
    off = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    nkt = np.maximum(nk[tri], 1)
    bins = (j0[tri] + off // nkt) * nz + (k0[tri] + off % nkt)
    order = np.argsort(bins, kind="stable")
    bin_tri = tri[order]
    bin_start = np.concatenate([[0], np.cumsum(np.bincount(bins, minlength=ny * nz))])

    pb = np.clip(np.floor((p[:, 1] - oy) / h + 0.5).astype(np.int64), 0, ny - 1) * nz + np.clip(
        np.floor((p[:, 2] - oz) / h + 0.5).astype(np.int64), 0, nz - 1
    )
    per_point = bin_start[pb + 1] - bin_start[pb]
    inside = np.zeros(idx.size, dtype=bool)
    for a, b in _pair_chunks(per_point, _MAX_PAIRS):
        c = per_point[a:b]
        tot = int(c.sum())
        if tot == 0:
            continue
        pid = np.repeat(np.arange(a, b), c)
        off = np.arange(tot) - np.repeat(np.cumsum(c) - c, c)
        t = bin_tri[bin_start[pb[pid]] + off]
        hit, xc = edges.crossings(t, p[pid, 1], p[pid, 2], cull=True)
        ph = pid[hit]
        before = np.bincount(ph[xc < p[ph, 0]] - a, minlength=b - a)
        after = np.bincount(ph[xc >= p[ph, 0]] - a, minlength=b - a)
        # odd totals (should not happen): inside only if both directions agree
        inside[a:b] = ((before & 1) == 1) & ((after & 1) == 1)
    result[idx] = inside
    return result
