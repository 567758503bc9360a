"""Smoothing kernels: the cubic spline W(r, h) and its gradient (Monaghan 1992), written with the
support radius h (W = 0 for r >= h), as in SPlisHSPlasH, in 2D and 3D; Akinci et al.'s (2013)
cohesion kernel C(r, h).

``W(q) = k (6 q^3 - 6 q^2 + 1)`` for ``q = r / h <= 1/2``, ``2 k (1 - q)^3`` for ``1/2 < q <= 1``,
with ``k = 8 / (pi h^3)`` in 3D and ``40 / (7 pi h^2)`` in 2D, so that the integral of W is 1.
With h = 2 x particle spacing, the lattice sums are exact to 1e-3 (tests/unit/test_sph_kernels.py).

Two halves: numpy functions (tests, boundary sampling) and ``make_kernels`` building Taichi funcs
with h, dim and the float type compiled in.
"""

from __future__ import annotations

import math

import numpy as np


def kernel_constant(h: float, dim: int) -> float:
    return 8.0 / (math.pi * h**3) if dim == 3 else 40.0 / (7.0 * math.pi * h**2)


def cubic_W(r: np.ndarray, h: float, dim: int) -> np.ndarray:
    """W(|r|, h) for distances ``r`` (numpy)."""
    q = np.asarray(r, dtype=np.float64) / h
    k = kernel_constant(h, dim)
    return np.where(q <= 0.5, k * (6 * q**3 - 6 * q**2 + 1), np.where(q <= 1.0, 2 * k * (1 - q) ** 3, 0.0))


def cubic_gradW(x: np.ndarray, h: float, dim: int) -> np.ndarray:
    """grad W(x, h) for displacement vectors ``x`` (n, dim) (numpy); zero at x = 0."""
    x = np.asarray(x, dtype=np.float64)
    r = np.linalg.norm(x, axis=-1)
    q = r / h
    k = kernel_constant(h, dim)
    dw = np.where(q <= 0.5, 6 * k * q * (3 * q - 2), np.where(q <= 1.0, -6 * k * (1 - q) ** 2, 0.0)) / h
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(r[..., None] > 1e-12 * h, x * (dw / np.where(r > 0, r, 1.0))[..., None], 0.0)
    return g


def _lattice(support_factor: float, dim: int) -> np.ndarray:
    """Points of the lattice of spacing 1 within ceil(support_factor) of the origin along each axis,
    (m, dim)."""
    n = int(np.ceil(support_factor))
    ax = np.arange(-n, n + 1, dtype=np.float64)
    return np.stack([c.ravel() for c in np.meshgrid(*[ax] * dim, indexing="ij")], axis=1)


def lattice_sum(support_factor: float, dim: int) -> float:
    """sum_j W(|x_j|) V over the infinite lattice of spacing 1 (V = 1) around a lattice point, support radius
    ``support_factor``: 1.00086 (2D) / 0.99997 (3D) at support 2, 1.0034 / 1.0018 at support 3. Particle mass
    and volume are divided by it, so that a lattice sits exactly at rest density: in 2D the bare kernel puts
    it 0.09-0.3% over, which Tait's n = 7 turns into a pressure at rest of 0.6-2.4% of the stiffness (a
    hidden background pressure of 300 Pa for water at 50 kPa, 340 Pa in the Taylor-Green case)."""
    g = _lattice(support_factor, dim)
    return float(cubic_W(np.linalg.norm(g, axis=1), support_factor, dim).sum())


VISC_EPS = 0.01  # regularisation of the viscosity terms: r^2 + VISC_EPS h^2 in the denominators


def morris_laplacian_constant(support_factor: float, dim: int) -> float:
    """c of the Morris et al. (1997) Laplacian, lap f_i = c sum_j V_j (f_i - f_j) (x_ij . grad W_ij) / (r^2 +
    VISC_EPS h^2), such that it is exact for a quadratic field on the lattice of spacing 1 (with the rest
    volume V = 1 / lattice_sum that the solver gives lattice particles): 2.085 in 2D at support 3, where the
    textbook
    2 is 4% weak (the regularisation and the finite support). Scale-free: the same for any spacing."""
    g = _lattice(support_factor, dim)
    r2 = (g * g).sum(1)
    m = (r2 > 0) & (r2 < support_factor**2)
    # neighbour j at x_j, particle i at the origin: x_ij = -x_j, grad W_ij = grad W(-x_j) = -grad W(x_j)
    xg = (g[m] * cubic_gradW(g[m], support_factor, dim)).sum(1)  # x_ij . grad W_ij (< 0)
    V = 1.0 / lattice_sum(support_factor, dim)
    # f = |x|^2 / 2 around i: lap f = dim; the sum gives c sum_j V (0 - r^2 / 2) xg / (r^2 + eps h^2)
    s = -0.5 * (V * r2[m] * xg / (r2[m] + VISC_EPS * support_factor**2)).sum()
    return float(dim / s)


def make_kernels(h: float, dim: int, f):
    """Taichi funcs ``W(r)``, ``gradW(x, r)`` (r = |x| given, to share the square root), the cohesion
    kernel ``C(r)`` and ``W_gradW(x, r)`` (both at once), with h, dim and the float type ``f`` compiled in."""
    from simcli.backend import stdout_to_stderr

    with stdout_to_stderr():
        import taichi as ti

    k = kernel_constant(h, dim)
    inv_h = 1.0 / h
    c_coh = 32.0 / (math.pi * h**9)  # Akinci et al. 2013, eq. 2 (3D normalisation, used in 2D too)
    h6_64 = h**6 / 64.0

    @ti.func
    def W(r):
        q = r * inv_h
        res = ti.cast(0.0, f)
        if q <= 1.0:
            if q <= 0.5:
                res = k * (6.0 * q * q * (q - 1.0) + 1.0)
            else:
                t = 1.0 - q
                res = 2.0 * k * t * t * t
        return res

    @ti.func
    def gradW(x, r):
        q = r * inv_h
        g = ti.Vector.zero(f, dim)
        if q <= 1.0 and r > 1e-9 * h:
            dw = 0.0
            if q <= 0.5:
                dw = 6.0 * k * q * (3.0 * q - 2.0)
            else:
                t = 1.0 - q
                dw = -6.0 * k * t * t
            g = x * (dw * inv_h / r)
        return g

    W_gradW_s = make_kernel_factor(h, dim, f)

    @ti.func
    def W_gradW(x, r):
        """W(r) and grad W(x) together (one q, one branch: the neighbour pass needs both)."""
        w, g, _s = W_gradW_s(x, r)
        return w, g

    @ti.func
    def C(r):
        res = ti.cast(0.0, f)
        if r < h and r > 0:
            a = (h - r) * r
            a3 = a * a * a
            if 2.0 * r > h:
                res = c_coh * a3
            else:
                res = c_coh * (2.0 * a3 - h6_64)
        return res

    return W, gradW, C, W_gradW


def make_cohesion_over_r(h: float, f):
    """Taichi func ``C_over_r(r) = C(r) / r``, Akinci et al.'s cohesion kernel over the distance (the force
    pass's pair term, C(r) / r (x_i - x_j)), with the division folded in: C = c a^3 with a = (h - r) r, so
    for r > h / 2 C / r = c (h - r)^3 r^2 (no division), and for r <= h / 2 C / r = c (2 (h - r)^3 r^2 -
    h^6 / (64 r)) (one, on an eighth of the pairs). The same value as make_kernels' C(r) / r to round-off
    (tests/unit/test_sph_kernels.py); 0 at r = 0 and beyond h."""
    from simcli.backend import stdout_to_stderr

    with stdout_to_stderr():
        import taichi as ti

    c_coh = 32.0 / (math.pi * h**9)  # as make_kernels
    h6_64 = h**6 / 64.0

    @ti.func
    def C_over_r(r):
        res = ti.cast(0.0, f)
        if r < h and r > 0:
            t = h - r
            b = t * t * t * (r * r)  # a^3 / r
            if 2.0 * r > h:
                res = c_coh * b
            else:
                res = c_coh * (2.0 * b - h6_64 / r)
        return res

    return C_over_r


def make_kernel_factor(h: float, dim: int, f):
    """Taichi func ``W_gradW_s(x, r) -> (W, grad W, s)`` with ``grad W = x s`` (s = W'(r) / r, 0 at r = 0 or
    beyond h): the neighbour lists store s instead of the vector (grad W_ij = (x_i - x_j) s_ij, rebuilt from
    the positions, which do not change within a substep's solves); make_kernels' W_gradW is this, less s."""
    from simcli.backend import stdout_to_stderr

    with stdout_to_stderr():
        import taichi as ti

    k = kernel_constant(h, dim)
    inv_h = 1.0 / h

    @ti.func
    def W_gradW_s(x, r):
        q = r * inv_h
        w = ti.cast(0.0, f)
        s = ti.cast(0.0, f)
        g = ti.Vector.zero(f, dim)
        if q <= 1.0:
            dw = 0.0
            if q <= 0.5:
                w = k * (6.0 * q * q * (q - 1.0) + 1.0)
                dw = 6.0 * k * q * (3.0 * q - 2.0)
            else:
                t = 1.0 - q
                w = 2.0 * k * t * t * t
                dw = -6.0 * k * t * t
            if r > 1e-9 * h:
                s = dw * inv_h / r
                g = x * s
        return w, g, s

    return W_gradW_s
