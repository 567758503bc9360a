"""The lattice another family's body is sampled on as SPH boundary particles (sph_fem.py, mpm_sph.py): SPH's
particle spacing fitted to the body's rest bounding box, points at the cells' centres (as SPH samples a Box
collider, solvers/sph/boundary.py), and the band of them within a depth of the body's surface."""

import numpy as np


def box_lattice(
    lo: np.ndarray, hi: np.ndarray, spacing: float
) -> "tuple[np.ndarray, np.ndarray, np.ndarray]":
    """(points (m, 3), counts n (3,), spacings s (3,)): round((hi - lo) / spacing) cells per axis (at least
    one), each s = (hi - lo) / n wide, a point at each cell's centre (C order over the axes)."""
    n = np.maximum(1, np.floor((hi - lo) / spacing + 0.5)).astype(int)
    s = (hi - lo) / n
    axes = [lo[a] + s[a] * (np.arange(n[a]) + 0.5) for a in range(len(n))]
    p = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(n))
    return p, n, s


def surface_band(inside: np.ndarray, n: np.ndarray, s: np.ndarray, depth: float) -> np.ndarray:
    """The points of a box_lattice that lie inside the body (``inside``, per point) and within ``depth`` of
    its surface, counted on the lattice: a point's distance to the nearest lattice point outside the body (a
    Euclidean distance transform, with a layer of outside points all round), which is its distance to the
    surface plus half a spacing for a box fitted to the lattice."""
    from scipy.ndimage import distance_transform_edt

    grid = np.pad(np.asarray(inside, bool).reshape(tuple(n)), 1)
    inner = tuple(slice(1, -1) for _ in n)
    dist = distance_transform_edt(grid, sampling=s)[inner].reshape(-1)
    return np.asarray(inside, bool) & (dist < depth + 0.5 * s.min())
