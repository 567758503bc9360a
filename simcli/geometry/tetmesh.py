"""Tetrahedral meshes of solid entities (numpy, no Taichi): FEM's elements and PBD.Elastic's soft bodies.

* Box morphs: structured Kuhn subdivision (each cell into 6 tetrahedra sharing its main diagonal,
  conforming across cells) at ``solvers.fem.resolution`` cells per metre.
* Mesh morphs whose file holds tetrahedra (Gmsh .msh, .vtu, Medit .mesh, ...; read with meshio):
  used as they are (scale, rotate, translate applied).
* Sphere, Cylinder and surface Mesh morphs: tetrahedralised with TetGen through the ``tetgen``
  Python package (pyvista/tetgen, AGPL-3.0, not a dependency of simcli: install it with
  ``pip install tetgen``), with a maximum volume and a minimum dihedral angle.

Every mesh is checked: no inverted or degenerate tetrahedron (reported by index), no unused vertex.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from simcli.geometry.mesh import MeshError, check_closed, load_mesh_morph, resolve_mesh_path, transform_points
from simcli.geometry.tetgen_worker import run_tetgen
from simcli.scene.morphs import BoxShape, CylinderShape, MeshShape, SphereShape

DEGENERATE_REL = 1e-10  # |6 V| below this x (longest edge)^3 is degenerate


@dataclass
class TetMesh:
    x: np.ndarray  # (n, 3) float64 vertices [m]
    tets: np.ndarray  # (m, 4) int64, positively oriented
    source: str = ""

    @property
    def volumes(self) -> np.ndarray:
        return signed_volumes(self.x, self.tets)


def signed_volumes(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a = x[tets[:, 0]]
    d1, d2, d3 = x[tets[:, 1]] - a, x[tets[:, 2]] - a, x[tets[:, 3]] - a
    return np.einsum("ij,ij->i", d1, np.cross(d2, d3)) / 6.0


def box_tets(lo, hi, resolution: float) -> TetMesh:
    """Structured tetrahedral mesh of the box [lo, hi]: ceil(L resolution) cells per axis, 6 tets per cell."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    n = np.maximum(1, np.ceil((hi - lo) * resolution - 1e-9)).astype(np.int64)
    axes = [np.linspace(lo[a], hi[a], n[a] + 1) for a in range(3)]
    X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)

    def vid(i, j, k):
        return (i * (n[1] + 1) + j) * (n[2] + 1) + k

    I, J, K = np.meshgrid(np.arange(n[0]), np.arange(n[1]), np.arange(n[2]), indexing="ij")
    I, J, K = I.reshape(-1), J.reshape(-1), K.reshape(-1)
    tets = []
    for perm in itertools.permutations(range(3)):
        c = np.zeros(3, dtype=np.int64)
        verts = [vid(I, J, K)]
        for a in perm:
            c[a] += 1
            verts.append(vid(I + c[0], J + c[1], K + c[2]))
        tets.append(np.stack(verts, axis=1))
    T = np.concatenate(tets)
    return TetMesh(X, orient(X, T), source="Box")


def orient(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Tets with negative volume get two vertices swapped (used for generated meshes only)."""
    tets = np.array(tets, dtype=np.int64)
    neg = signed_volumes(x, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return tets


def validate(mesh: TetMesh, name: str) -> TetMesh:
    """Reject inverted or degenerate tetrahedra (with their index); drop unused vertices."""
    x, t = mesh.x, mesh.tets
    if t.ndim != 2 or t.shape[1] != 4 or t.shape[0] == 0:
        raise MeshError(f"{name}: no tetrahedra")
    if t.min() < 0 or t.max() >= x.shape[0]:
        raise MeshError(f"{name}: tetrahedron vertex index outside 0..{x.shape[0] - 1}")
    vol = signed_volumes(x, t)
    edges = np.stack([x[t[:, i]] - x[t[:, j]] for i, j in itertools.combinations(range(4), 2)], axis=1)
    lmax = np.linalg.norm(edges, axis=2).max(axis=1)
    degenerate = np.abs(6.0 * vol) <= DEGENERATE_REL * lmax**3
    if degenerate.any():
        idx = np.nonzero(degenerate)[0]
        raise MeshError(
            f"{name}: {idx.size} degenerate tetrahedra (zero volume), first at index "
            f"{int(idx[0])}: {idx[:10].tolist()}"
        )
    inverted = vol < 0
    if inverted.any():
        idx = np.nonzero(inverted)[0]
        raise MeshError(
            f"{name}: {idx.size} inverted tetrahedra (negative volume), first at index "
            f"{int(idx[0])}: {idx[:10].tolist()}; fix the vertex order of the input mesh"
        )
    used = np.zeros(x.shape[0], dtype=bool)
    used[t.reshape(-1)] = True
    if not used.all():
        remap = np.cumsum(used) - 1
        x, t = x[used], remap[t]
    return TetMesh(np.ascontiguousarray(x), np.ascontiguousarray(t), mesh.source)


def boundary_faces(tets: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Outward-oriented boundary triangles (faces used by one tetrahedron)."""
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    opp = np.concatenate([tets[:, 0], tets[:, 1], tets[:, 2], tets[:, 3]])
    _, inv, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    keep = counts[inv.reshape(-1)] == 1
    faces, opp = faces[keep], opp[keep]
    a, b, c = x[faces[:, 0]], x[faces[:, 1]], x[faces[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), x[opp] - a) > 0
    faces[inward] = faces[inward][:, [0, 2, 1]]
    return faces


def locate_in_tets(x: np.ndarray, tets: np.ndarray, p: np.ndarray, k: int = 16, tol: float = 0.0, binv=None):
    """(tet (len(p),) int, -1 where none; lam (len(p), 4)): the tetrahedron of (x, tets) holding each point
    and its barycentric coordinates, the first among the ``k`` whose centroids are nearest with every
    coordinate >= -``tol`` (3D; enough for meshes of shape-regular tetrahedra). ``binv``: the tetrahedra's
    inverse edge matrices, if the caller has them."""
    from scipy.spatial import cKDTree

    tet = np.full(len(p), -1, np.int64)
    lam = np.zeros((len(p), 4))
    if not len(p) or not len(tets):
        return tet, lam
    X = x[tets]
    ok = np.ones(len(tets), bool)
    if binv is None:
        D = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], axis=2)
        ok = np.abs(np.linalg.det(D)) > 1e-30
        binv = np.zeros_like(D)
        binv[ok] = np.linalg.inv(D[ok])
    kq = min(len(tets), k)
    _, cand = cKDTree(X.mean(axis=1)).query(p, k=kq)
    cand = np.asarray(cand).reshape(len(p), kq)
    for c in range(kq):
        todo = np.flatnonzero(tet < 0)
        if not len(todo):
            break
        e = cand[todo, c]
        l3 = np.einsum("nij,nj->ni", binv[e], p[todo] - X[e, 0])
        w = np.concatenate([1.0 - l3.sum(axis=1, keepdims=True), l3], axis=1)
        hit = ok[e] & np.all(w >= -tol, axis=1)
        tet[todo[hit]] = e[hit]
        lam[todo[hit]] = w[hit]
    return tet, lam


def points_in_tets(x: np.ndarray, tets: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(len(p),) bool: which points lie in one of the tetrahedra (x, tets) (locate_in_tets)."""
    inside = np.zeros(len(p), bool)
    if not len(p) or not len(tets):
        return inside
    lo, hi = x.min(axis=0), x.max(axis=0)
    near = np.flatnonzero(np.all((p >= lo) & (p <= hi), axis=1))
    if len(near):
        inside[near] = locate_in_tets(x, tets, p[near])[0] >= 0
    return inside


# ------------------------------------------------------------------ tetrahedralisation


def _sphere_surface(center, radius, h):
    """Icosphere subdivided until its edges are about h."""
    t = (1 + 5**0.5) / 2
    v = np.array(
        [
            [-1, t, 0],
            [1, t, 0],
            [-1, -t, 0],
            [1, -t, 0],
            [0, -1, t],
            [0, 1, t],
            [0, -1, -t],
            [0, 1, -t],
            [t, 0, -1],
            [t, 0, 1],
            [-t, 0, -1],
            [-t, 0, 1],
        ],
        dtype=np.float64,
    )
    f = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ]
    )
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    while radius * 1.05 > h * 1.0 and len(f) < 200000 and _edge(v, f) * radius > h:
        v, f = _subdivide(v, f)
    return np.asarray(center) + radius * v, f


def _edge(v, f):
    return float(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1).mean())


def _subdivide(v, f):
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(edges, axis=0, return_inverse=True)
    mid = v[uniq[:, 0]] + v[uniq[:, 1]]
    mid /= np.linalg.norm(mid, axis=1, keepdims=True)
    m = len(v) + inv.reshape(3, -1)
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = m[0], m[1], m[2]
    nf = np.concatenate(
        [
            np.stack([a, ab, ca], 1),
            np.stack([b, bc, ab], 1),
            np.stack([c, ca, bc], 1),
            np.stack([ab, bc, ca], 1),
        ]
    )
    return np.concatenate([v, mid]), nf


def _cylinder_surface(c: CylinderShape, h):
    ax = "xyz".index(c.axis)
    nseg = max(12, int(math.ceil(2 * math.pi * c.radius / h)))
    nz = max(1, int(math.ceil(c.height / h)))
    ang = 2 * math.pi * np.arange(nseg) / nseg
    ring = np.stack([c.radius * np.cos(ang), c.radius * np.sin(ang)], axis=1)
    zs = np.linspace(-c.height / 2, c.height / 2, nz + 1)
    pts = [np.column_stack([ring, np.full(nseg, z)]) for z in zs]
    pts += [np.array([[0.0, 0.0, -c.height / 2]]), np.array([[0.0, 0.0, c.height / 2]])]
    P = np.concatenate(pts)
    F = []
    for k in range(nz):
        for i in range(nseg):
            a, b = k * nseg + i, k * nseg + (i + 1) % nseg
            F += [[a, b, b + nseg], [a, b + nseg, a + nseg]]
    bot, top = (nz + 1) * nseg, (nz + 1) * nseg + 1
    for i in range(nseg):
        F.append([bot, (i + 1) % nseg, i])
        F.append([top, nz * nseg + i, nz * nseg + (i + 1) % nseg])
    # local (radial, radial, axis) -> world
    perm = {2: [0, 1, 2], 0: [2, 0, 1], 1: [1, 2, 0]}[ax]
    W = np.zeros_like(P)
    for k in range(3):
        W[:, perm[k]] = P[:, k]
    return W + np.asarray(c.center), np.asarray(F, dtype=np.int64)


def tetrahedralise(verts: np.ndarray, tris: np.ndarray, max_volume: float, min_dihedral: float, name: str):
    """Tetrahedralise a closed surface with TetGen (``pip install tetgen``)."""
    try:
        import tetgen  # noqa: PLC0415
    except ImportError:
        raise MeshError(
            f"{name}: tetrahedralising a surface needs the 'tetgen' package (pyvista/tetgen, AGPL-3.0), "
            "which is not installed: pip install tetgen. Alternatively mesh the shape yourself (e.g. gmsh) "
            "and give the tetrahedral mesh file (.msh, .vtu, .mesh) as a Mesh morph, or use a Box morph."
        ) from None
    del tetgen  # only its presence is checked here: it runs in a child process
    check_closed(np.asarray(tris), name)
    status, nodes, elems = run_tetgen(
        verts,
        tris,
        order=1,
        mindihedral=float(min_dihedral),
        minratio=1.5,
        maxvolume=float(max_volume),
        quality=True,
        nobisect=False,
        verbose=0,
    )
    if status == "crashed":
        raise MeshError(
            f"{name}: TetGen crashed on this surface (exit {nodes}): it is most likely self-intersecting "
            "(overlapping parts, duplicate or degenerate triangles). Repair the surface (e.g. MeshLab: "
            "remove duplicates and self-intersections; Blender 3D-Print toolbox), or mesh it yourself "
            "and give the tetrahedral mesh file"
        )
    if status == "error":
        raise MeshError(f"{name}: TetGen failed ({nodes}); the surface is probably self-intersecting")
    if len(elems) == 0:
        raise MeshError(f"{name}: TetGen produced no tetrahedra (self-intersecting or open surface?)")
    return np.asarray(nodes, dtype=np.float64), np.asarray(elems, dtype=np.int64)


def read_tets(morph: MeshShape, scene_dir):
    """Tetrahedra of a Mesh morph's file, or None when it holds only a surface."""
    import meshio

    path = resolve_mesh_path(morph.file, scene_dir)
    if not path.exists():
        raise MeshError(f"mesh file not found: '{morph.file}' (looked for '{path}')")
    m = meshio.read(path)
    tets = [np.asarray(b.data[:, :4], dtype=np.int64) for b in m.cells if b.type in ("tetra", "tetra10")]
    if not tets:
        return None
    x = transform_points(
        np.asarray(m.points, dtype=np.float64)[:, :3], morph.scale, morph.rotate, morph.translate
    )
    T = np.concatenate(tets)
    if np.linalg.det(np.diag(np.broadcast_to(np.asarray(morph.scale, dtype=np.float64), (3,)))) < 0:
        T = T[:, [0, 2, 1, 3]]  # a mirroring scale flips every orientation
    return x, T


def mesh_for_entity(entity, opts, scene_dir=None) -> TetMesh:
    """The validated tetrahedral mesh of an entity's morph; ``opts``: a ``simcli.scene.meshing.Meshing``
    or FEMOptions (the same fields)."""
    m = entity.morph
    name = f"entity '{entity.name}'"
    h = 1.0 / float(opts.resolution)
    max_vol = float(opts.max_volume) if opts.max_volume is not None else h**3 / 6.0
    hs = 1.0 / float(opts.surface_resolution or opts.resolution)
    if isinstance(m, BoxShape):
        lo, hi = m.bounds()
        if len(lo) != 3:
            raise MeshError(f"{name}: FEM needs a 3D scene")
        mesh = box_tets(lo, hi, opts.resolution)
    elif isinstance(m, SphereShape):
        v, f = _sphere_surface(m.center, m.radius, hs)
        x, t = tetrahedralise(v, f, max_vol, opts.min_dihedral, name)
        mesh = TetMesh(x, orient(x, t), "Sphere")
    elif isinstance(m, CylinderShape):
        v, f = _cylinder_surface(m, hs)
        x, t = tetrahedralise(v, f, max_vol, opts.min_dihedral, name)
        mesh = TetMesh(x, orient(x, t), "Cylinder")
    elif isinstance(m, MeshShape):
        got = read_tets(m, scene_dir)
        if got is not None:
            mesh = TetMesh(got[0], got[1], str(m.file))
        else:
            surf = load_mesh_morph(m, scene_dir)  # closed-mesh check, orientation
            x, t = tetrahedralise(surf.vertices, surf.triangles, max_vol, opts.min_dihedral, name)
            mesh = TetMesh(x, orient(x, t), str(m.file))
    else:  # pragma: no cover
        raise MeshError(f"{name}: unsupported morph {m.type}")
    return validate(mesh, name)


def estimate_counts(entity, opts, scene_dir=None) -> tuple[int, int]:
    """(vertices, tetrahedra) an FEM entity's morph will have, without meshing it: exact for Box morphs
    and tetrahedral mesh files, from the volume and max_volume for TetGen's meshes (its tetrahedra
    average about half the bound)."""
    m = entity.morph
    h = 1.0 / float(opts.resolution)
    max_vol = float(opts.max_volume) if opts.max_volume is not None else h**3 / 6.0
    if isinstance(m, BoxShape):
        lo, hi = m.bounds()
        n = [max(1, math.ceil((b - a) * float(opts.resolution) - 1e-9)) for a, b in zip(lo, hi)]
        return math.prod(k + 1 for k in n), 6 * math.prod(n)
    if isinstance(m, SphereShape):
        vol = 4.0 / 3.0 * math.pi * m.radius**3
    elif isinstance(m, CylinderShape):
        vol = math.pi * m.radius**2 * m.height
    else:
        got = read_tets(m, scene_dir)
        if got is not None:
            return got[0].shape[0], got[1].shape[0]
        surf = load_mesh_morph(m, scene_dir)
        lo, hi = surf.vertices.min(axis=0), surf.vertices.max(axis=0)
        vol = float(np.prod(hi - lo))  # bounding box: an upper bound
    tets = max(1, int(2.0 * vol / max_vol))
    return tets // 5 + 1, tets
