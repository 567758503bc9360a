"""Probe sampling on plain numpy arrays (no Taichi, no solver): what the recorder applies to the arrays the
solvers expose, and what the unit tests check on synthetic arrays.

Point values are Shepard-normalised kernel averages, ``sum_j w_j W(|x - x_j|, h) A_j / sum_j w_j W(...)``
(w_j: the particle's volume, or 1), returned as the two sums so that several entities combine; the
value is NaN where the denominator is zero (no particle within reach).
"""

from __future__ import annotations

import numpy as np

from simcli.solvers.sph.kernels import cubic_W  # numpy only


def kernel_sums(
    x: np.ndarray, values: np.ndarray, at, h: float, weights: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """(sum_j w_j W_j A_j, sum_j w_j W_j) over the particles ``x`` (n, dim) within ``h`` of ``at``, with the
    cubic spline W of support radius ``h``; ``values`` (n,) or (n, c)."""
    x = np.asarray(x, dtype=np.float64)
    at = np.asarray(at, dtype=np.float64)
    dim = x.shape[1]
    values = np.asarray(values, dtype=np.float64)
    vshape = values.shape[1:]
    if x.shape[0] == 0:
        return np.zeros(vshape), 0.0
    # cheap box cull before the distances
    near = np.all(np.abs(x - at) < h, axis=1)
    idx = np.nonzero(near)[0]
    if idx.size == 0:
        return np.zeros(vshape), 0.0
    r = np.linalg.norm(x[idx] - at, axis=1)
    w = cubic_W(r, h, dim)
    if weights is not None:
        w = w * np.asarray(weights, dtype=np.float64)[idx]
    den = float(w.sum())
    num = np.tensordot(w, values[idx], axes=(0, 0))
    return np.asarray(num, dtype=np.float64), den


def finish(num, den: float):
    """The kernel average from its two sums: NaN(s) where no particle is within reach."""
    num = np.asarray(num, dtype=np.float64)
    if den <= 0.0:
        return np.full(num.shape, np.nan)
    return num / den


def point_average(x, values, at, h, weights=None):
    """A kernel-weighted average at ``at`` (NaN where no particle is within ``h``)."""
    return finish(*kernel_sums(x, values, at, h, weights))


def grid_interpolate(data: np.ndarray, origin, spacing, at) -> np.ndarray:
    """Trilinear (bilinear in 2D) interpolation of cell-centred grid data at ``at``.

    ``data``: VTK order, (nz, ny, nx[, c]) in 3D or (ny, nx[, c]) in 2D; ``origin`` (lower corner of the grid)
    and ``spacing`` in x, y[, z] order. Points within half a cell of the boundary take the boundary cells'
    value along that axis (clamped)."""
    dim = len(origin)
    a = np.asarray(data, dtype=np.float64)
    # to x, y, z index order
    axes = tuple(reversed(range(dim))) + tuple(range(dim, a.ndim))
    a = a.transpose(axes)
    shape = a.shape[:dim]
    i0, frac = [], []
    for d in range(dim):
        s = (float(at[d]) - float(origin[d])) / float(spacing[d]) - 0.5
        s = min(max(s, 0.0), shape[d] - 1.0)
        lo = min(int(np.floor(s)), shape[d] - 2) if shape[d] > 1 else 0
        i0.append(lo)
        frac.append(s - lo if shape[d] > 1 else 0.0)
    out = np.zeros(a.shape[dim:])
    for corner in range(1 << dim):
        w = 1.0
        idx = []
        for d in range(dim):
            bit = (corner >> d) & 1
            w *= frac[d] if bit else 1.0 - frac[d]
            idx.append(min(i0[d] + bit, shape[d] - 1))
        if w != 0.0:
            out = out + w * a[tuple(idx)]
    return out


def surface_height(
    x: np.ndarray, at, axis: int, radius: float, half: float, gap: float | None = None
) -> float:
    """The free-surface coordinate along ``axis`` over the column of radius ``radius`` through ``at`` (the
    coordinates along the other axes, in order): the highest particle in it plus ``half``; NaN if none.
    With ``gap``: the highest particle connected to the column's lowest one, the particles sorted along
    ``axis`` up to the first step wider than ``gap`` (spray above the liquid is not its surface)."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape[0] == 0:
        return float("nan")
    dim = x.shape[1]
    others = [a for a in range(dim) if a != axis]
    d2 = np.zeros(x.shape[0])
    for a, c in zip(others, at):
        d2 += (x[:, a] - float(c)) ** 2
    inside = d2 <= radius * radius
    if not inside.any():
        return float("nan")
    h = x[inside, axis]
    if gap is None:
        return float(h.max() + half)
    h = np.sort(h)
    wide = np.flatnonzero(np.diff(h) > gap)
    return float((h[wide[0]] if len(wide) else h[-1]) + half)


def totals(quantity: str, mass: np.ndarray, x=None, v=None, energy=None) -> tuple[np.ndarray, float]:
    """Additive sums of one entity for a total probe: (sum, total mass). ``com`` returns sum m x, divided by
    the total mass by :func:`finish_total` once every entity is added."""
    m = np.asarray(mass, dtype=np.float64)
    if quantity == "mass":
        s = np.asarray(m.sum())
    elif quantity == "kinetic_energy":
        vv = np.asarray(v, dtype=np.float64)
        s = np.asarray(0.5 * float(np.dot(m, np.einsum("ij,ij->i", vv, vv))))
    elif quantity == "momentum":
        s = m @ np.asarray(v, dtype=np.float64)
    elif quantity == "com":
        s = m @ np.asarray(x, dtype=np.float64)
    elif quantity == "elastic_energy":
        s = np.asarray(float(np.asarray(energy, dtype=np.float64).sum()))
    else:
        raise ValueError(f"unknown total quantity {quantity!r}")
    return s, float(m.sum())


def finish_total(quantity: str, s, mass: float):
    s = np.asarray(s, dtype=np.float64)
    if quantity == "com":
        return s / mass if mass > 0 else np.full(s.shape, np.nan)
    return s
