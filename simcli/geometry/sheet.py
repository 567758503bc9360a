"""Triangle sheets shared by the cloth models of two families (numpy, no Taichi): PBD.Cloth
(simcli.solvers.pbd.topology) and FEM.Cloth (simcli.solvers.fem.cloth.topology) take the same Rectangle
(criss-cross triangulation) and open triangle Mesh morphs, so one morph gives both the same mesh; and the
bending hinges of a sheet with their signed dihedral angles.

Dihedral angle (Bridson, Marino and Fedkiw 2003, "Simulation of clothing with folds and wrinkles", sec. 4):
for the interior edge (x3, x4) between the triangles (x1, x3, x4) and (x2, x4, x3), E = x4 - x3,
n1 = (x1 - x3) x (x1 - x4), n2 = (x2 - x4) x (x2 - x3) and the signed angle
theta = atan2((n1^ x n2^) . E^, n1^ . n2^) (0 for a flat sheet).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def sheet_axes(normal) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """In-plane axes (u, v) and unit normal of a Rectangle: u = x projected onto the sheet (y when the
    normal is close to x), v = n x u."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = ref - ref.dot(n) * n
    u /= np.linalg.norm(u)
    return u, np.cross(n, u), n


def rectangle_mesh(morph) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and triangles (m, 3) of a Rectangle morph; quad diagonals alternate (criss-cross
    pattern), so the sheet has no preferred shear direction."""
    nu, nv = ([morph.resolution] * 2) if isinstance(morph.resolution, int) else list(morph.resolution)
    u, v, _ = sheet_axes(morph.normal)
    a = (np.arange(nu + 1) / nu - 0.5) * morph.size[0]
    b = (np.arange(nv + 1) / nv - 0.5) * morph.size[1]
    A, B = np.meshgrid(a, b, indexing="ij")
    x = np.asarray(morph.center, dtype=np.float64) + A.reshape(-1, 1) * u + B.reshape(-1, 1) * v
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.reshape(-1), j.reshape(-1)
    p00, p10, p01, p11 = (
        i * (nv + 1) + j,
        (i + 1) * (nv + 1) + j,
        i * (nv + 1) + j + 1,
        (i + 1) * (nv + 1) + j + 1,
    )
    flip = (i + j) % 2 == 1
    t1 = np.where(flip[:, None], np.stack([p00, p10, p01], 1), np.stack([p00, p10, p11], 1))
    t2 = np.where(flip[:, None], np.stack([p10, p11, p01], 1), np.stack([p00, p11, p01], 1))
    return x, np.concatenate([t1, t2]).astype(np.int64)


def read_open_surface(morph, scene_dir) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of a (possibly open) surface Mesh morph, transformed: a cloth mesh need not be closed."""
    from simcli.geometry.mesh import (
        MeshError,
        MeshFileNotFoundError,
        _clean,
        _read_obj,
        _triangles_from_cells,
        resolve_mesh_path,
        transform_points,
    )

    path = resolve_mesh_path(morph.file, scene_dir)
    if not Path(path).is_file():
        raise MeshFileNotFoundError(
            f"mesh file not found: '{morph.file}' (looked for '{path}'; relative paths "
            "are relative to the scene file's folder)"
        )
    import warnings

    import meshio

    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            mesh = meshio.read(str(path))
        tris = _triangles_from_cells(mesh, str(path))
        pts = np.asarray(mesh.points, dtype=np.float64)
    except Exception as exc:
        if not str(path).lower().endswith(".obj"):
            raise MeshError(f"cannot read mesh '{path}': {exc}") from exc
        pts, tris = _read_obj(str(path))
    pts, tris = _clean(pts, np.asarray(tris, dtype=np.int64), str(path))
    try:
        x = transform_points(pts, morph.scale, morph.rotate, morph.translate)
    except ValueError as exc:
        raise MeshError(f"mesh '{morph.file}': {exc}") from None
    return x, tris


def bending_quads(tris: np.ndarray) -> np.ndarray:
    """(x1, x2, x3, x4) per interior edge (x3, x4) shared by exactly two triangles, x1 and x2 the wing tips,
    ordered so that triangle 1 is (x1, x3, x4) as listed in ``tris`` (consistent orientation keeps the
    sign of the angle meaningful)."""
    he = np.concatenate([tris[:, [0, 1, 2]], tris[:, [1, 2, 0]], tris[:, [2, 0, 1]]])  # a, b (edge), opposite
    key = np.sort(he[:, :2], axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    ks = key[order]
    same = np.all(ks[1:] == ks[:-1], axis=1)
    quads = []
    starts = np.nonzero(same)[0]  # edges of more than two triangles: each pair of neighbours
    for s in starts:
        h1, h2 = he[order[s]], he[order[s + 1]]
        a, b, c = h1  # triangle (a, b, c): edge a -> b, tip c
        d = h2[2]
        quads.append((c, d, b, a))
    return np.asarray(quads, dtype=np.int64).reshape(-1, 4)


def dihedral_angles(x: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Signed dihedral angles [rad] (see the module docstring) of the quads (x1, x2, x3, x4)."""
    x1, x2, x3, x4 = (x[quads[:, k]] for k in range(4))
    E = x4 - x3
    n1 = np.cross(x1 - x3, x1 - x4)
    n2 = np.cross(x2 - x4, x2 - x3)
    n1 /= np.maximum(np.linalg.norm(n1, axis=1, keepdims=True), 1e-300)
    n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-300)
    e = E / np.maximum(np.linalg.norm(E, axis=1, keepdims=True), 1e-300)
    return np.arctan2(np.einsum("ij,ij->i", np.cross(n1, n2), e), np.einsum("ij,ij->i", n1, n2))
