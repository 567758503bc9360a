"""`type: Mesh` colliders: a closed triangle surface turned into a signed-distance grid at build time.

Host side (numpy + scipy, no Taichi; :func:`build_sdf`):

* the surface is read, checked closed and transformed (scale, rotate, translate) by
  simcli.geometry.mesh, exactly as a `Mesh` morph;
* a grid of cell ``h`` covers the mesh's bounding box plus a margin of ``MARGIN_CELLS`` cells; the sign
  of every node comes from the lattice ray-parity test of simcli.geometry.mesh (robust on edges and
  vertices); nodes within ``BAND_CELLS`` cells of a triangle's bounding box get the exact distance to the
  nearest triangle (closest point on a triangle, vectorised; a mesh of many small triangles: each node near
  the surface against its ``NEAREST_K`` nearest triangles by centroid), the others a distance transform of
  the inside mask (scipy), bounded below by the band: the field is exact where contact happens and
  monotone (a usable gradient) deep inside;
* ``h`` is half the finest of the MPM grid cell, the PBD particle_size and the FEM element size 1/resolution
  of the families present (``sdf_cell`` overrides it), coarsened if the grid would exceed ``MAX_NODES``.

Kernel side (simcli.collider_mesh_kernels.MeshSDFField): the grid in a Taichi field, sampled trilinearly in
the collider's body
frame (its pose at t = 0), the normal the normalised gradient of the trilinear interpolant; outside the
grid the collider is far (phi = ``FAR``). Because the field is in the body frame, simcli.colliders'
ColliderPoses moves and turns it like any primitive.
"""

import functools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

MARGIN_CELLS = 4  # grid cells around the mesh's bounding box
BAND_CELLS = 3  # exact distances within this many cells of a triangle's bounding box
MAX_NODES = 200**3  # the grid is coarsened beyond this many nodes
FAR = 1.0e3  # phi outside the grid [m]


class GridSDF:
    """A closed outline in its body frame (its pose at t = 0) and its signed-distance node grid, in 2D or 3D
    alike (the dimension is ``phi.ndim``): the host side shared by :class:`MeshSDF` (a closed triangle
    surface) and simcli.rigid.polygon.PolygonSDF (a closed polygon). A subclass sets ``vertices`` (n, d),
    ``origin`` (d,) (position of node 0), ``h`` (the cell) and ``phi`` (the node values, < 0 inside)."""

    vertices: np.ndarray
    origin: np.ndarray
    h: float
    phi: np.ndarray

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(int(s) for s in self.phi.shape)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def sample(self, x: np.ndarray) -> np.ndarray:
        """Multilinear phi (bilinear in 2D, trilinear in 3D) at body-frame points x (k, d), as the kernels
        sample it (FAR outside the grid)."""
        from scipy.ndimage import map_coordinates

        x = np.asarray(x, float).reshape(-1, self.phi.ndim)
        g = (x - self.origin) / self.h
        hi = np.asarray(self.shape) - 1
        inside = np.all((g >= 0) & (g <= hi), axis=1)
        out = np.full(len(x), FAR)
        if np.any(inside):
            out[inside] = map_coordinates(self.phi, g[inside].T, order=1, mode="nearest")
        return out

    def normal(self, x: np.ndarray) -> np.ndarray:
        """Unit outward normals (k, d) at body-frame points x: the multilinear phi's central differences over
        half a cell (zero where the grid gives no gradient, e.g. outside it)."""
        dim = self.phi.ndim
        x = np.asarray(x, float).reshape(-1, dim)
        g = np.zeros_like(x)
        for ax in range(dim):
            d = np.zeros(dim)
            d[ax] = 0.5 * self.h
            g[:, ax] = self.sample(x + d) - self.sample(x - d)
        return g / np.maximum(np.linalg.norm(g, axis=1), 1e-300)[:, None]


@dataclass(eq=False)
class MeshSDF(GridSDF):
    """A closed mesh (body frame = its pose at t = 0) and its signed-distance grid (3D)."""

    vertices: np.ndarray  # (n, 3)
    triangles: np.ndarray  # (m, 3), outward
    origin: np.ndarray  # (3,) position of node (0, 0, 0) [m]
    h: float  # grid cell [m]
    phi: np.ndarray  # (nx, ny, nz) float64, < 0 inside
    source: str
    build_seconds: float
    volume: float


# ------------------------------------------------------------------ exact distances


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Distance from points p (k, 3) to triangles (a, b, c) (k, 3 each), row by row (Ericson's closest
    point on a triangle, vectorised)."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        q = a + ab * v[:, None] + ac * w[:, None]  # interior
        # edges
        t_ab = np.clip(np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0), 0, 1)
        t_ac = np.clip(np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0), 0, 1)
        t_bc = np.clip(np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0), 0, 1)
    reg_a = (d1 <= 0) & (d2 <= 0)
    reg_b = (d3 >= 0) & (d4 <= d3)
    reg_c = (d6 >= 0) & (d5 <= d6)
    reg_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    reg_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    reg_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    q = np.where(reg_bc[:, None], b + (c - b) * t_bc[:, None], q)
    q = np.where(reg_ac[:, None], a + ac * t_ac[:, None], q)
    q = np.where(reg_ab[:, None], a + ab * t_ab[:, None], q)
    q = np.where(reg_c[:, None], c, q)
    q = np.where(reg_b[:, None], b, q)
    q = np.where(reg_a[:, None], a, q)
    return np.linalg.norm(p - q, axis=1)


def mesh_distance(V: np.ndarray, T: np.ndarray, points: np.ndarray, chunk: int = 1 << 20) -> np.ndarray:
    """Unsigned distance from every point (k, 3) to the mesh (brute force over triangles in chunks; for
    checks and measurements on a few thousand points, not for the grid)."""
    p = np.asarray(points, float).reshape(-1, 3)
    out = np.full(len(p), np.inf)
    nt = len(T)
    step = max(1, chunk // max(1, nt))
    A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    for s in range(0, len(p), step):
        q = p[s : s + step]
        k = len(q)
        d = point_triangle_distance(
            np.repeat(q, nt, axis=0), np.tile(A, (k, 1)), np.tile(B, (k, 1)), np.tile(C, (k, 1))
        )
        out[s : s + step] = d.reshape(k, nt).min(axis=1)
    return out


def _band_distances(V, T, origin, h, shape, band: float) -> np.ndarray:
    """Exact unsigned distance at every node within ``band`` of a triangle's bounding box (inf elsewhere)."""
    nx, ny, nz = shape
    dist = np.full(nx * ny * nz, np.inf)
    A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    lo = np.minimum(np.minimum(A, B), C) - band
    hi = np.maximum(np.maximum(A, B), C) + band
    i0 = np.clip(np.ceil((lo - origin) / h).astype(np.int64), 0, np.asarray(shape) - 1)
    i1 = np.clip(np.floor((hi - origin) / h).astype(np.int64), 0, np.asarray(shape) - 1)
    n = np.maximum(i1 - i0 + 1, 0)
    counts = n[:, 0] * n[:, 1] * n[:, 2]
    max_pairs = 1 << 21
    start = 0
    while start < len(T):
        # a run of triangles with at most max_pairs (triangle, node) pairs (at least one triangle)
        cum = np.cumsum(counts[start:])
        stop = start + max(1, int(np.searchsorted(cum, max_pairs, side="right")))
        c = counts[start:stop]
        tot = int(c.sum())
        if tot:
            tri = np.repeat(np.arange(start, stop), c)
            off = np.arange(tot) - np.repeat(np.cumsum(c) - c, c)
            ny_, nz_ = n[tri, 1], n[tri, 2]
            ii = i0[tri, 0] + off // (ny_ * nz_)
            jj = i0[tri, 1] + (off // nz_) % ny_
            kk = i0[tri, 2] + off % nz_
            p = origin + h * np.stack([ii, jj, kk], axis=1)
            d = point_triangle_distance(p, A[tri], B[tri], C[tri])
            np.minimum.at(dist, (ii * ny + jj) * nz + kk, d)
        start = stop
    return dist.reshape(shape)


MAX_BOX_PAIRS = 4_000_000  # (triangle, node) pairs of the box enumeration before the nearest-triangle path
NEAREST_K = 16  # triangles per node in the nearest-triangle path


def _pair_count(V, T, origin, h, shape, band) -> int:
    A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    lo = np.minimum(np.minimum(A, B), C) - band
    hi = np.maximum(np.maximum(A, B), C) + band
    top = np.asarray(shape) - 1
    i0 = np.clip(np.ceil((lo - origin) / h).astype(np.int64), 0, top)
    i1 = np.clip(np.floor((hi - origin) / h).astype(np.int64), 0, top)
    return int(np.prod(np.maximum(i1 - i0 + 1, 0), axis=1).sum())


def _near_distances(V, T, origin, h, edt, band) -> np.ndarray:
    """Exact distance at the nodes within ``band`` (+ a cell) of the inside/outside boundary (by the
    distance transform ``edt``) to the nearest of the NEAREST_K triangles whose centroids are closest (a
    mesh of triangles small against the cell: the nearest triangle is among them); inf elsewhere."""
    from scipy.spatial import cKDTree

    dist = np.full(edt.shape, np.inf)
    idx = np.nonzero(edt <= band + 1.5 * h)
    p = origin + h * np.stack(idx, axis=1).astype(float)
    A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    k = min(NEAREST_K, len(T))
    tree = cKDTree((A + B + C) / 3.0)
    out = np.empty(len(p))
    step = max(1, (1 << 21) // k)
    for s0 in range(0, len(p), step):
        q = p[s0 : s0 + step]
        _, nb = tree.query(q, k=k)
        nb = nb.reshape(len(q), k).ravel()
        d = point_triangle_distance(np.repeat(q, k, axis=0), A[nb], B[nb], C[nb])
        out[s0 : s0 + step] = d.reshape(len(q), k).min(axis=1)
    dist[idx] = out
    return dist


# ------------------------------------------------------------------ building


@functools.lru_cache(maxsize=8)
def _build_cached(path: str, mtime_ns: int, size: int, scale, rotate, translate, h: float) -> MeshSDF:
    from scipy.ndimage import distance_transform_edt

    from simcli.geometry.mesh import TriMesh, lattice_inside_mesh, load_mesh_morph

    t0 = time.perf_counter()

    class _Morph:  # the fields load_mesh_morph reads
        pass

    m = _Morph()
    m.file, m.scale, m.rotate, m.translate = path, scale, list(rotate), list(translate)
    mesh = load_mesh_morph(m, None)
    V, T = mesh.vertices, mesh.triangles
    lo, hi = mesh.bounds
    margin = MARGIN_CELLS * h
    shape = np.ceil((hi - lo + 2 * margin) / h).astype(np.int64) + 1
    while int(np.prod(shape)) > MAX_NODES:  # coarsen
        h *= 1.25
        margin = MARGIN_CELLS * h
        shape = np.ceil((hi - lo + 2 * margin) / h).astype(np.int64) + 1
    origin = lo - margin
    shape = tuple(int(s) for s in shape)
    inside = lattice_inside_mesh(
        TriMesh(V, T, mesh.volume, mesh.source), origin, h, shape, thin_check_axes=()
    ).inside
    band = BAND_CELLS * h
    d_in = distance_transform_edt(inside) * h
    d_out = distance_transform_edt(~inside) * h
    if _pair_count(V, T, origin, h, shape, band) <= MAX_BOX_PAIRS:
        exact = _band_distances(V, T, origin, h, shape, band)
    else:  # many small triangles: each node near the surface against its nearest triangles
        exact = _near_distances(V, T, origin, h, np.where(inside, d_in, d_out), band)
    # far from the surface: a distance transform of the inside/outside masks (voxel centres), never
    # below the band (where the exact distance was not taken the true one exceeds it)
    far = np.maximum(np.where(inside, d_in, d_out) - 0.5 * h, band)
    unsigned = np.where(np.isfinite(exact), exact, far)
    phi = np.where(inside, -unsigned, unsigned)
    return MeshSDF(
        vertices=V,
        triangles=T,
        origin=np.asarray(origin, float),
        h=float(h),
        phi=phi,
        source=mesh.source,
        build_seconds=time.perf_counter() - t0,
        volume=float(mesh.volume),
    )


def default_cell(scene: Any) -> float | None:
    """Half the finest length of the families present (MPM grid cell, PBD and SPH particle_size, FEM
    1/resolution, the SF cell)."""
    fams = getattr(scene, "families", set())
    cands = []
    if "SPH" in fams:
        cands.append(scene.solvers.sph.particle_size)
    if "SF" in fams:
        lo, hi = scene.domain.bounds(scene.sim.dim)
        cands.append(min(scene.solvers.sf.cells(lo, hi)[1]))
    if "MPM" in fams:
        cands.append(scene.solvers.mpm.dx)
    if "PBD" in fams:
        cands.append(scene.solvers.pbd.particle_size)
    if "FEM" in fams:
        cands.append(1.0 / scene.solvers.fem.resolution)
    return 0.5 * min(cands) if cands else None


def build_sdf(c: Any, scene: Any = None, scene_dir: Any = None) -> MeshSDF:
    """The signed-distance grid of a Mesh collider model (cached per file, transform and cell).
    Raises simcli.geometry.mesh.MeshError (a ValueError) for a file that is missing, unreadable, open,
    non-manifold or encloses no volume."""
    from simcli.geometry.mesh import MeshError, MeshFileNotFoundError, resolve_mesh_path

    path = resolve_mesh_path(c.file, scene_dir)
    try:
        st = path.stat()
    except OSError:
        raise MeshFileNotFoundError(
            f"mesh file not found: '{c.file}' (looked for '{path}'; relative paths are relative to the "
            "scene file's folder)"
        ) from None
    if not path.is_file():
        raise MeshError(f"mesh path is not a file: '{path}'")
    h = c.sdf_cell or (default_cell(scene) if scene is not None else None)
    scale = c.scale if isinstance(c.scale, (int, float)) else tuple(float(v) for v in c.scale)
    if h is None:  # no family to take it from: 1/64 of the mesh's extent
        from simcli.geometry.mesh import read_surface, transform_points

        V, _T = read_surface(path)
        x = transform_points(V, scale, c.rotate, c.translate)
        h = float(np.max(x.max(axis=0) - x.min(axis=0))) / 64.0
    try:
        return _build(path, st, scale, c, h)
    except MeshError:
        raise
    except (ValueError, IndexError) as ex:  # e.g. nothing left once opposite duplicate faces cancel
        raise MeshError(
            f"mesh '{c.file}' is degenerate: no triangle of it bounds a volume (it is flat, or every face "
            f"comes twice with opposite orientations; {ex}); give a closed surface around a volume"
        ) from None


def _build(path: Path, st: Any, scale: Any, c: Any, h: float) -> MeshSDF:
    return _build_cached(
        str(path.resolve()),
        st.st_mtime_ns,
        st.st_size,
        scale,
        tuple(float(v) for v in c.rotate),
        tuple(float(v) for v in c.translate),
        float(h),
    )


def mesh_spec_numbers(c: Any, dim: int, scene: Any = None, scene_dir: Any = None) -> tuple:
    """(MeshSDF, bounding-box centre, half its diagonal) of a Mesh collider: simcli.colliders' ColliderSpec
    takes a = the centre and radius = the half diagonal (the reach counted by substeps: auto)."""
    if dim != 3:
        raise ValueError("Mesh colliders exist only in 3D (use Box, Sphere or Plane colliders in 2D)")
    sdf = build_sdf(c, scene, scene_dir)
    lo, hi = sdf.bounds
    return sdf, tuple(float(v) for v in 0.5 * (lo + hi)), 0.5 * float(np.linalg.norm(hi - lo))


def inside_mesh_collider(c: Any, x: np.ndarray, scene: Any = None, scene_dir: Any = None) -> np.ndarray:
    """Points (k, 3) strictly inside a Mesh collider at t = 0 (its SDF grid, as the solvers see it)."""
    return build_sdf(c, scene, scene_dir).sample(x) < 0


# ------------------------------------------------------------------ checks (validate)


def check_collider(c: Any, scene: Any, scene_dir: Any) -> list[tuple[tuple, str]]:
    """(path below the collider, message) for a Mesh collider that cannot be used and for restitution where
    no family applies it."""
    out: list[tuple[tuple, str]] = []
    dim = scene.sim.dim
    if getattr(c, "restitution", 0.0) > 0:
        fem = scene.solvers.fem
        if "FEM" in scene.families and fem.integrator != "explicit":
            out.append(
                (
                    ("restitution",),
                    f"restitution on colliders is applied by the explicit FEM integrator only (this scene's "
                    f"solvers.fem.integrator is {fem.integrator}): set it to explicit or restitution to 0",
                )
            )
        if scene.families & {"SPH", "SF"}:
            out.append(
                (
                    ("restitution",),
                    "restitution is applied to MPM, PBD and FEM entities only; this scene has "
                    f"{', '.join(sorted(scene.families & {'SPH', 'SF'}))} entities (set restitution to 0)",
                )
            )
    if c.type != "Mesh":
        return out
    if dim != 3:
        out.append((("type",), "Mesh colliders need dim 3 (use Box, Sphere or Plane colliders in 2D)"))
        return out
    for key, n in (("rotate", 3), ("translate", 3)):
        if len(getattr(c, key)) != n:
            out.append(((key,), f"expected {n} components (got {len(getattr(c, key))})"))
    if not isinstance(c.scale, (int, float)) and len(c.scale) not in (1, 3):
        out.append((("scale",), f"give one factor or 3 (x, y, z), got {len(c.scale)}"))
    factors = [c.scale] if isinstance(c.scale, (int, float)) else list(c.scale)
    if any(not (1e-9 <= abs(float(f)) <= 1e9) for f in factors):
        # (a scale of 1e300 overflowed into numpy warnings and an OSError's text as the message)
        out.append((("scale",), f"give factors between 1e-9 and 1e9 in magnitude (got {c.scale})"))
    if out:
        return out
    try:
        sdf = build_sdf(c, scene, scene_dir)
    except (ValueError, OSError, ArithmeticError) as ex:  # ArithmeticError: e.g. a scale of 1e300
        msg = str(ex)
        if "not a closed surface" in msg:
            msg = msg.replace(
                "Filling a mesh with particles needs", "A Mesh collider's signed distance needs"
            ).replace(" or use a tetrahedral mesh", "")
        if "encloses no volume" in msg:
            msg += ": it is flat or degenerate; give a closed surface around a volume"
        return [(("file",), msg)]
    lo, hi = sdf.bounds
    # FEM.Cloth meets a Mesh collider's triangles themselves (no grid): a thin plate is fine there
    sdf_users = set(scene.families) - {"FEMCloth"}
    if sdf_users and np.min(hi - lo) < 2 * sdf.h:
        out.append(
            (
                ("file",),
                f"the mesh is thinner ({np.min(hi - lo):.3g} m) than two cells of its signed-distance grid "
                f"({sdf.h:.3g} m): particles would pass through it; thicken it or set sdf_cell below "
                f"{np.min(hi - lo) / 2:.3g}",
            )
        )
    return out


def exact_depth(c: Any, x_body: np.ndarray, scene: Any = None, scene_dir: Any = None) -> float:
    """Deepest of the body-frame points (k, 3) inside a Mesh collider [m], by the exact distance to its
    triangles (ray parity for inside; the SDF grid only preselects candidates); 0 if none is inside."""
    from simcli.geometry.mesh import TriMesh, points_inside_mesh

    sdf = build_sdf(c, scene, scene_dir)
    x = np.asarray(x_body, float).reshape(-1, 3)
    cand = x[sdf.sample(x) < 2 * sdf.h]  # every point inside or near (the grid's error is below a cell)
    if not len(cand):
        return 0.0
    ins = points_inside_mesh(TriMesh(sdf.vertices, sdf.triangles, sdf.volume, sdf.source), cand)
    if not np.any(ins):
        return 0.0
    return float(mesh_distance(sdf.vertices, sdf.triangles, cand[ins]).max())
