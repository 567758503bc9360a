"""Walls and static colliders without boundary particles (``solvers.sph.boundary: volume_map``): each
boundary's contribution to a liquid particle's sums is precomputed once, as a function of the particle's
position, and looked up per particle in the density pass instead of walking boundary particles.

What a boundary contributes (density.py) is a handful of sums over its particles b, each a smooth function
of the liquid particle's position x only (for a static boundary)::

    psi(x)  = sum_b V_b W(x - x_b)                (density: rho_i += rho0_i psi)
    B(x)    = sum_b V_b grad W(x - x_b) = grad psi (pressure terms, DFSPH's alpha)
    cnt(x)  = #{b : |x - x_b| < h}                (DFSPH's neighbour count test)
    T(x)    = -sum_b V_b W'(r) r                  (gradient_correction: scalar, the moment's trace)
    M(x)    = sum_b V_b / (r^2 + eps) grad W (x - x_b)^T   (no-slip viscosity)

so this is a density map (Koschier & Bender 2017, "Density maps for improved SPH boundary handling") of
the boundary the particle model samples: B is the exact gradient of psi (the pressure force of the walls is
the gradient of the density they add), rather than Bender et al.'s (2019, "Volume maps: an implicit
boundary representation for SPH") volume V_b(x) at the closest point x_b, whose force is not the gradient
of its density term. The boundary itself is the one ``boundary: particles`` samples (boundary.py: layers of
spacing particle_size outside each face, volume V_rest each), so a liquid lattice next to a wall is at rest
density as with particles.

* Domain walls: the box's faces are planes, so the sums depend on the distances d_a to the faces within the
  support only. A face's layers, averaged over their tangential offset (the lattice sum taken as an
  integral along the face, a lattice in the normal direction), give a table in d (``H``). The walls are
  the union of the faces' half-spaces; inclusion-exclusion removes the edges' lattice counted twice
  (``Q``, a table in two distances: lattice in both normals) and restores the corners' (3D: ``O``, a lattice
  sum in three distances). Exact to the tables' interpolation for any box; the hydrostatic moment (the
  extrapolated wall pressure) is corrected the same way (session 10: counted twice at the edges it kicked the
  DFSPH tank's lower corners), and so is the no-slip matrix, whose edges and corners take the first face's
  kind and velocity as boundary particles do (boundary.wall_particles).
* Static colliders: the collider's boundary particles (boundary.collider_particles, the same sampling) are
  deposited on a grid of spacing particle_size / 4 (2D) or / 3 (3D) by cloud-in-cell weights and
  convolved with the kernel's stencils (FFT), once at build; each liquid particle interpolates the grid
  (multilinear). Moving colliders keep boundary particles for now (an error says so).

Cost per liquid particle: nothing unless it lies within a support radius of a wall (a few distance tests);
then one table lookup per face, edge and corner in reach. No boundary particles in the neighbour lists or
the cell sort.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from simcli.solvers.sph.kernels import VISC_EPS, kernel_constant

# table resolutions: points per support radius (face: 1D, edge: 2D, corner: 3D)
N_FACE = 256
N_EDGE = 64
N_CORNER = 32


def _W(r: np.ndarray, h: float, dim: int) -> np.ndarray:
    """W(r) (numpy; kernels.cubic_W without float powers: the tables evaluate it millions of times)."""
    q = np.asarray(r, dtype=np.float64) / h
    k = kernel_constant(h, dim)
    t = np.maximum(1.0 - q, 0.0)
    return np.where(q <= 0.5, k * (6.0 * q * q * (q - 1.0) + 1.0), 2.0 * k * t * t * t)


def _dW(r: np.ndarray, h: float, dim: int) -> np.ndarray:
    """W'(r) [1/m^(dim+1)] (numpy)."""
    q = np.asarray(r, dtype=np.float64) / h
    k = kernel_constant(h, dim)
    t = np.maximum(1.0 - q, 0.0)
    return np.where(q <= 0.5, 6.0 * k * q * (3.0 * q - 2.0), -6.0 * k * t * t) / h


def _integrands(a: list[np.ndarray], t2: np.ndarray, h: float, dim: int, eps: float) -> dict[str, np.ndarray]:
    """The sums' integrands at normal offsets a (one array per normal, u_a = a) with t2 the squared
    tangential offset (0 where there is none): psi, the gradient along each normal, cnt, T, and the
    no-slip matrix's normal-normal and tangential parts (one tangential component: t2 / (dim - len(a)))."""
    r2 = sum(x * x for x in a) + t2
    r = np.sqrt(r2)
    dw = _dW(r, h, dim)
    safe = np.where(r > 1e-12 * h, r, 1.0)
    out = {"psi": _W(r, h, dim), "cnt": (r < h).astype(np.float64), "T": -dw * r}
    for k, x in enumerate(a):
        out[f"g{k}"] = np.where(r > 1e-12 * h, dw * x / safe, 0.0)
    c = np.where(r > 1e-12 * h, dw / (safe * (r2 + eps)), 0.0)
    out["ann"] = c * a[0] * a[0]
    ntan = dim - len(a)
    out["att"] = c * (t2 / ntan if ntan else 0.0 * t2)
    m = np.where(r > 1e-12 * h, dw / safe, 0.0)  # the moment sum_b V_b grad W (x - x_b)^T
    out["mnn"] = m * a[0] * a[0]
    out["mtt"] = m * (t2 / ntan if ntan else 0.0 * t2)
    # the moment's components in the normals' frame (edges, corners): m a_k a_l, and along the edge's axis
    for k in range(len(a)):
        for l in range(k, len(a)):
            out[f"m{k}{l}"] = m * a[k] * a[l]
            out[f"c{k}{l}"] = c * a[k] * a[l]  # the no-slip matrix's
    out["ctt"] = c * (t2 / ntan if ntan else 0.0 * t2)
    return out


@dataclass
class WallTables:
    """Tables of the domain walls' sums against the distances to the faces [0, h]."""

    h: float
    face: np.ndarray  # (N_FACE + 1, 8): psi, g, cnt, T, ann, att (no-slip), mnn, mtt (moment)
    edge: np.ndarray  # (N_EDGE + 1, N_EDGE + 1, 5): psi, g0, g1, cnt, T
    corner: np.ndarray | None  # 3D: (N_CORNER + 1,) * 3 + (6,): psi, g0, g1, g2, cnt, T


def wall_tables(ps: float, h: float, dim: int, V: float) -> WallTables:
    """The walls' tables (numpy): each boundary particle has volume V, layers at (k + 1/2) ps beyond a face.
    Along a face the lattice is summed as a particle aligned with it sees it. Computed once per (dim,
    h / ps, V / ps^dim) at unit spacing and scaled (psi, cnt and T are scale-free, the gradient scales
    as 1 / ps, the no-slip matrix as 1 / ps^2)."""
    t = _unit_wall_tables(dim, round(h / ps, 12), round(V / ps**dim, 12))
    face = t.face * np.array([1.0, 1.0 / ps, 1.0, 1.0, ps**-2, ps**-2, 1.0, 1.0])
    edge = t.edge * np.array([1.0, 1.0 / ps, 1.0 / ps, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0] + [ps**-2] * 4)
    corner = None
    if t.corner is not None:
        corner = t.corner * np.array([1.0, 1.0 / ps, 1.0 / ps, 1.0 / ps] + [1.0] * 8 + [ps**-2] * 6)
    return WallTables(h, face, edge, corner)


@functools.lru_cache(maxsize=8)
def _unit_wall_tables(dim: int, h: float, V: float) -> WallTables:
    ps = 1.0
    eps = VISC_EPS * h * h
    L = int(math.ceil(h / ps)) + 1  # layers in reach
    layers = (np.arange(L) + 0.5) * ps
    # along the faces: the lattice sum of a particle aligned with the wall's lattice (a liquid lattice
    # next to a wall then sits at rho0 as with wall particles; the integral along the face, the average over
    # the tangential offset, differs from it by 0.15% in 2D)
    kt = np.arange(-L - 1, L + 2, dtype=np.float64) * ps
    if dim == 2:
        t2_1, w_1 = kt * kt, np.full(kt.size, ps)
    else:
        t2_1 = (kt[:, None] ** 2 + kt[None, :] ** 2).ravel()
        w_1 = np.full(t2_1.size, ps * ps)
    # face: a lattice in the normal, the tangential dim - 1 integrated
    d = np.linspace(0.0, h, N_FACE + 1)
    a = (d[:, None] + layers[None, :])[..., None]  # (nd, L, 1)
    it = _integrands([a], t2_1[None, None, :], h, dim, eps)
    fac = V / ps ** (dim - 1)
    face = np.stack(
        [
            fac * (it[k] * w_1).sum(axis=(1, 2)) * (1.0 / V if k == "cnt" else 1.0)
            for k in ("psi", "g0", "cnt", "T", "ann", "att", "mnn", "mtt")
        ],
        axis=-1,
    )
    # edge: a lattice in both normals; 3D: the third axis integrated (row by row: bounded memory)
    d2 = np.linspace(0.0, h, N_EDGE + 1)
    fac = V / ps ** (dim - 2)
    keys = ("psi", "g0", "g1", "cnt", "T", "m00", "m11", "m01", "mtt", "c00", "c11", "c01", "ctt")
    edge = np.zeros((d2.size, d2.size, len(keys)))
    if dim == 3:
        tl = kt
        w_t = ps
    for i0, x0 in enumerate(d2):
        a0 = np.broadcast_to((x0 + layers)[None, :, None], (d2.size, L, L))
        a1 = np.broadcast_to(d2[:, None, None] + layers[None, None, :], (d2.size, L, L))
        if dim == 2:
            it = _integrands([a0, a1], np.zeros(1), h, dim, eps)
            row = [it[k].sum(axis=(1, 2)) for k in keys]
        else:
            it = _integrands([a0[..., None], a1[..., None]], (tl * tl)[None, None, None, :], h, dim, eps)
            row = [it[k].sum(axis=(1, 2, 3)) * w_t for k in keys]
        edge[i0] = np.stack([fac * r * (1.0 / V if k == "cnt" else 1.0) for k, r in zip(keys, row)], axis=-1)
    corner = None
    if dim == 3:
        d3 = np.linspace(0.0, h, N_CORNER + 1)
        A = [
            d3.reshape([-1 if i == k else 1 for i in range(3)] + [1, 1, 1])
            + layers.reshape([1, 1, 1] + [-1 if i == k else 1 for i in range(3)])
            for k in range(3)
        ]
        it = _integrands(A, np.zeros(1), h, dim, eps)
        corner = np.stack(
            [
                V * it[k].sum(axis=(3, 4, 5)) * (1.0 / V if k == "cnt" else 1.0)
                for k in (
                    *("psi", "g0", "g1", "g2", "cnt", "T", "m00", "m11", "m22", "m01", "m02", "m12"),
                    *("c00", "c11", "c22", "c01", "c02", "c12"),
                )
            ],
            axis=-1,
        )
    return WallTables(h, face, edge, corner)


@dataclass
class ColliderMap:
    """A static collider's sums on a grid: origin, spacing, channels (psi, g (dim), cnt, T[, M sym])."""

    origin: np.ndarray
    spacing: float
    values: np.ndarray  # dims + (channels,): psi, g (dim), cnt, T, moment (sym), no-slip matrix (sym)
    no_slip: bool
    nparticles: int = 0
    sym: list = field(default_factory=list)  # (i, j) of the moment's and the no-slip matrix's channels
    moving: bool = False  # in the collider's body frame (its pose at t = 0), queried through ColliderPoses


def collider_map(spec, lo, hi, ps: float, h: float, dim: int, V: float, layers: int) -> ColliderMap | None:
    """The collider's boundary particles (boundary.collider_particles, each with its sampled volume times
    V / ps^dim, as boundary: particles gives them) deposited on a grid and convolved with the kernel's
    stencils; None if none lies in reach of the domain."""
    from scipy.signal import fftconvolve

    from simcli.solvers.sph.boundary import collider_particles

    if spec.moving:  # its whole shell, in its body frame, as boundary particles sample it (moving.py)
        from simcli.solvers.sph.moving import moving_bounds

        lo, hi = moving_bounds(spec, lo, hi)
    bp = collider_particles(spec, lo, hi, ps, dim, layers)
    if bp.n == 0:
        return None
    dx = ps / (4.0 if dim == 2 else 3.0)
    K = int(math.ceil(h / dx))
    origin = bp.x.min(axis=0) - (K + 2) * dx
    dims = np.ceil((bp.x.max(axis=0) + (K + 2) * dx - origin) / dx).astype(np.int64) + 1
    # cloud-in-cell deposit of V_b (and of 1, the count)
    s = (bp.x - origin) / dx
    i0 = np.floor(s).astype(np.int64)
    fr = s - i0
    vol = bp.volume * (V / ps**dim)
    dep = np.zeros(tuple(dims))
    depc = np.zeros(tuple(dims))
    for corner in range(2**dim):
        off = np.array([(corner >> k) & 1 for k in range(dim)])
        w = np.prod(np.where(off, fr, 1.0 - fr), axis=1)
        idx = tuple((i0 + off).T)
        np.add.at(dep, idx, vol * w)
        np.add.at(depc, idx, w)
    # stencils: u = node - x_b on the offsets k dx, |k| <= K
    ax = np.arange(-K, K + 1) * dx
    U = np.stack(np.meshgrid(*[ax] * dim, indexing="ij"), axis=-1)
    r2 = (U * U).sum(-1)
    r = np.sqrt(r2)
    dw = _dW(r, h, dim)
    safe = np.where(r > 1e-12 * h, r, 1.0)
    eps = VISC_EPS * h * h
    chans = [fftconvolve(dep, _W(r, h, dim), mode="same")]
    for k in range(dim):
        chans.append(fftconvolve(dep, np.where(r > 1e-12 * h, dw * U[..., k] / safe, 0.0), mode="same"))
    chans.append(fftconvolve(depc, (r < h).astype(np.float64), mode="same"))
    chans.append(fftconvolve(dep, -dw * r, mode="same"))
    sym = [(i, j) for i in range(dim) for j in range(i, dim)]
    m = np.where(r > 1e-12 * h, dw / safe, 0.0)
    for i, j in sym:  # the moment sum_b V_b grad W (x - x_b)^T (the walls' hydrostatic pressure)
        chans.append(fftconvolve(dep, m * U[..., i] * U[..., j], mode="same"))
    no_slip = bool(spec.contact == "sticky")
    if no_slip:
        c = np.where(r > 1e-12 * h, dw / (safe * (r2 + eps)), 0.0)
        for i, j in sym:
            chans.append(fftconvolve(dep, c * U[..., i] * U[..., j], mode="same"))
    return ColliderMap(origin, dx, np.stack(chans, axis=-1), no_slip, bp.n, sym, bool(spec.moving))


class VolumeMap:
    """Host side: the tables and grids of a scene's static boundaries, their Taichi fields, and the Taichi
    func ``boundary(xi)`` that density.py calls per liquid particle."""

    def __init__(self, scene, dim: int, ps: float, h: float, V: float, specs, layers: int) -> None:
        from simcli.colliders import wall_specs

        self.dim, self.ps, self.h = dim, ps, h
        lo, hi = scene.domain.bounds(dim)
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.walls = wall_specs(scene, dim)
        self.wall_tables = wall_tables(ps, h, dim, V)
        self.colliders = []
        self.spec_index = []  # the collider index (ColliderPoses) of each map
        for k, spec in enumerate(specs):
            m = collider_map(spec, lo, hi, ps, h, dim, V, layers)
            if m is not None:
                self.colliders.append(m)
                self.spec_index.append(k)
        self.named = [c for c, k in enumerate(self.spec_index) if specs[k].name is not None]
        # free rigid bodies' maps: their hydrostatic wall term is not clamped at zero (see ``hydrostatic``)
        self.rigid = [bool(getattr(specs[k], "rigid", False)) for k in self.spec_index]
        self.no_slip = any(w.contact == "sticky" for w in self.walls) or any(
            m.no_slip for m in self.colliders
        )

    def nbytes(self) -> int:
        t = self.wall_tables
        n = t.face.nbytes + t.edge.nbytes + (0 if t.corner is None else t.corner.nbytes)
        return n + sum(m.values.nbytes for m in self.colliders)

    def describe(self) -> str:
        parts = [f"domain walls: tables of {N_FACE + 1} (faces), {N_EDGE + 1}^2 (edges)"]
        if self.dim == 3:
            parts[-1] += f", {N_CORNER + 1}^3 (corners)"
        for k, m in enumerate(self.colliders):
            parts.append(
                f"collider {k}: grid {tuple(int(s) for s in m.values.shape[:-1])} of {m.spacing:.3g} m "
                f"({m.nparticles} boundary particles deposited)"
            )
        return "; ".join(parts)

    # ---------------------------------------------------------------- Taichi side

    def build(
        self,
        f,
        npf,
        with_noslip: bool,
        with_hyd: bool = False,
        poses=None,
        F=None,
        fn=None,
        with_moment: bool = False,
    ):
        """Taichi fields and the func ``boundary(xi, g, i) -> (psi, B, cnt, T, M, m_w, S, H, Mom, Q)`` (liquid
        particle i at xi, its neighbour list built); ``with_noslip``: the no-slip sums are wanted (a viscous
        liquid); ``with_hyd``: H, the walls' hydrostatic pressure term for gravity g (the extrapolated wall
        pressure, see ``hydrostatic``; needs the solver's fields ``F`` and funcs ``fn``), else zero;
        ``with_moment``: Mom = sum_b V_b grad W_ib (x_i - x_b)^T, the boundary's part of the moment matrix
        that DFSPH's matrix gradient correction inverts (``gradient_correction: true``, density.py), and Q =
        sum_b V_b grad W_ib v_b^T (its wall-velocity term: B v^T of each moving face and collider, as S takes
        B . v), else zero. Mom is the hydrostatic term's moment, summed over the faces, edges, corners and
        colliders with the same inclusion-exclusion."""
        from simcli.backend import stdout_to_stderr

        with stdout_to_stderr():
            import taichi as ti

        dim, h = self.dim, self.h
        t = self.wall_tables
        face = ti.Vector.field(t.face.shape[-1], f, shape=t.face.shape[0])
        face.from_numpy(t.face.astype(npf))
        edge = ti.Vector.field(t.edge.shape[-1], f, shape=t.edge.shape[:2])
        edge.from_numpy(t.edge.astype(npf))
        corner = None
        if t.corner is not None:
            corner = ti.Vector.field(t.corner.shape[-1], f, shape=t.corner.shape[:3])
            corner.from_numpy(t.corner.astype(npf))
        cols = []
        for m in self.colliders:
            fld = ti.Vector.field(m.values.shape[-1], f, shape=m.values.shape[:-1])
            fld.from_numpy(m.values.astype(npf))
            cols.append(fld)
        self._fields = (face, edge, corner, cols)  # keep them alive
        col_meta = [
            (tuple(float(o) for o in m.origin), 1.0 / m.spacing, tuple(int(s) for s in m.values.shape[:-1]))
            for m in self.colliders
        ]
        col_noslip = [m.no_slip and with_noslip for m in self.colliders]
        col_sym = [m.sym for m in self.colliders]
        col_moving = [m.moving for m in self.colliders]  # queried in the body frame through ``poses``
        col_k = list(self.spec_index)
        col_rigid = list(self.rigid)
        any_rigid = any(col_rigid)
        body_limit, klim = self._make_body_limit(f, F, fn, with_hyd and any_rigid)
        lo = tuple(float(v) for v in self.lo)
        hi = tuple(float(v) for v in self.hi)
        # faces: (axis, side, inward normal sign, no-slip, velocity)
        faces = [
            (w.axis, w.side, -w.side, w.contact == "sticky" and with_noslip, tuple(w.velocity))
            for w in self.walls
        ]
        any_vel = [any(abs(c) > 0 for c in fc[4]) for fc in faces]
        sF, sE, sC = N_FACE / h, N_EDGE / h, N_CORNER / h

        def make_lerp1(tab, n):
            @ti.func
            def lerp1(s):
                u = ti.min(ti.max(s, 0.0), ti.cast(n, f) - 1e-4)
                k = ti.min(ti.cast(ti.floor(u), ti.i32), n - 1)
                w = u - k
                return tab[k] * (1.0 - w) + tab[k + 1] * w

            return lerp1

        def make_lerp2(tab, n):
            @ti.func
            def lerp2(s0, s1):
                u0 = ti.min(ti.max(s0, 0.0), ti.cast(n, f) - 1e-4)
                u1 = ti.min(ti.max(s1, 0.0), ti.cast(n, f) - 1e-4)
                k0 = ti.min(ti.cast(ti.floor(u0), ti.i32), n - 1)
                k1 = ti.min(ti.cast(ti.floor(u1), ti.i32), n - 1)
                w0, w1 = u0 - k0, u1 - k1
                return (tab[k0, k1] * (1.0 - w1) + tab[k0, k1 + 1] * w1) * (1.0 - w0) + (
                    tab[k0 + 1, k1] * (1.0 - w1) + tab[k0 + 1, k1 + 1] * w1
                ) * w0

            return lerp2

        def make_lerp3(tab, n):
            @ti.func
            def lerp3(s0, s1, s2):
                u0 = ti.min(ti.max(s0, 0.0), ti.cast(n, f) - 1e-4)
                u1 = ti.min(ti.max(s1, 0.0), ti.cast(n, f) - 1e-4)
                u2 = ti.min(ti.max(s2, 0.0), ti.cast(n, f) - 1e-4)
                k0 = ti.min(ti.cast(ti.floor(u0), ti.i32), n - 1)
                k1 = ti.min(ti.cast(ti.floor(u1), ti.i32), n - 1)
                k2 = ti.min(ti.cast(ti.floor(u2), ti.i32), n - 1)
                w0, w1, w2 = u0 - k0, u1 - k1, u2 - k2
                res = tab[k0, k1, k2] * 0.0
                for c in ti.static(range(8)):
                    a0, a1, a2 = c & 1, (c >> 1) & 1, (c >> 2) & 1
                    wt = (w0 if a0 else 1.0 - w0) * (w1 if a1 else 1.0 - w1) * (w2 if a2 else 1.0 - w2)
                    res += wt * tab[k0 + a0, k1 + a1, k2 + a2]
                return res

            return lerp3

        def make_grid_lerp(fld, dims):
            @ti.func
            def grid_lerp(s):
                """Multilinear interpolation at grid coordinates s; zero outside the grid."""
                res = fld[(0,) * dim] * 0.0
                inside = True
                for a in ti.static(range(dim)):
                    if s[a] < 0.0 or s[a] >= dims[a] - 1:
                        inside = False
                if inside:
                    k = ti.Vector([ti.cast(ti.floor(s[a]), ti.i32) for a in ti.static(range(dim))])
                    w = s - k
                    for c in ti.static(range(2**dim)):
                        wt = ti.cast(1.0, f)
                        off = ti.Vector([(c >> a) & 1 for a in ti.static(range(dim))])
                        for a in ti.static(range(dim)):
                            wt *= w[a] if (c >> a) & 1 else 1.0 - w[a]
                        res += wt * fld[k + off]
                return res

            return grid_lerp

        face_at = make_lerp1(face, N_FACE)
        edge_at = make_lerp2(edge, N_EDGE)
        corner_at = make_lerp3(corner, N_CORNER) if corner is not None else None
        col_at = [make_grid_lerp(cols[c], col_meta[c][2]) for c in range(len(cols))]

        @ti.func
        def hydrostatic(Bo, Mo, g, lim):
            """One boundary's hydrostatic term sum_b V_b kh_b grad W_ib with kh_b = g . (x_b - x_i), the
            stiffness difference of a liquid at rest between the boundary point and the particle: -Mo g
            with Mo = sum_b V_b grad W_ib (x_i - x_b)^T. Its part along the boundary's normal (-Bo) may push
            the liquid off the boundary but pull it by at most lim |Bo|: Adami et al. (2012) clamp the
            hydrostatic part at zero, lim = 0 (a wall above the liquid never pulls); a free rigid body's
            keeps the unclamped value as long as the boundary's total k stays >= 0, lim = the Shepard average
            of the liquid's last total k (``_make_body_limit``), as its boundary particles do
            (wall_pressure.mark). Clamped at zero, the face of a body above the liquid (its bottom) pushed
            with the liquid's k at the particle's depth, not at its own height: the 3D cube (0.06 m, rho 500,
            particle 0.01 m) floated at -6.7% draft on maps; unclamped -2.4%."""
            Hv = -(Mo @ g)
            bn = Bo.norm()
            if bn > 0:
                nh = -Bo / bn
                hn = Hv.dot(nh) - lim * bn
                if hn > 0:
                    Hv -= hn * nh
            return Hv

        def make_collider_at(c):
            @ti.func
            def collider_at(xi):
                """Collider map c at world point xi: (psi, B, cnt, T, moment, no-slip matrix, surface
                velocity), vectors and matrices in the world frame. A moving collider's (or rigid body's) map
                is its body frame's: the point goes to the body frame at the substep's middle pose
                (ColliderPoses slot 0, as moving boundary particles take it), x0 = R^T (x - c) + p, and the
                map's gradient and matrices come back rotated (R B, R M R^T); the scalars do not change."""
                org, inv = ti.static(col_meta[c][0], col_meta[c][1])
                nsym = ti.static(len(col_sym[c]))
                xq = xi
                Rm = ti.Matrix.identity(f, dim)
                vs = ti.Vector.zero(f, dim)
                if ti.static(col_moving[c]):
                    Rm, cen, vel, w = poses.get(0, col_k[c])
                    xq = Rm.transpose() @ (xi - cen) + poses.pivot[col_k[c]]
                    vs = vel + poses.cross(w, xi - cen)  # the surface's velocity at x_i
                v = col_at[c]((xq - ti.Vector(org, dt=f)) * inv)
                Bo = ti.Vector.zero(f, dim)
                for a in ti.static(range(dim)):
                    Bo[a] = v[1 + a]
                Mo = ti.Matrix.zero(f, dim, dim)  # the moment's channels, then the no-slip matrix's
                Mc = ti.Matrix.zero(f, dim, dim)
                for m in ti.static(range(nsym)):
                    i, j = ti.static(col_sym[c][m][0], col_sym[c][m][1])
                    if ti.static(with_hyd or with_moment):
                        Mo[i, j] = v[3 + dim + m]
                        Mo[j, i] = v[3 + dim + m]
                    if ti.static(col_noslip[c]):
                        Mc[i, j] = v[3 + dim + nsym + m]
                        Mc[j, i] = v[3 + dim + nsym + m]
                if ti.static(col_moving[c]):
                    Bo = Rm @ Bo
                    Mo = Rm @ Mo @ Rm.transpose()
                    Mc = Rm @ Mc @ Rm.transpose()
                return v[0], Bo, v[1 + dim], v[2 + dim], Mo, Mc, vs

            return collider_at

        collider_at = [make_collider_at(c) for c in range(len(cols))]

        @ti.func
        def boundary(xi, g, i):
            Hy = ti.Vector.zero(f, dim)
            psi = ti.cast(0.0, f)
            B = ti.Vector.zero(f, dim)
            cnt = ti.cast(0.0, f)
            T = ti.cast(0.0, f)
            M = ti.Matrix.zero(f, dim, dim)
            mw = ti.Vector.zero(f, dim)
            S = ti.cast(0.0, f)
            Mom = ti.Matrix.zero(f, dim, dim)  # with_moment: sum_b V_b grad W_ib (x_i - x_b)^T
            Q = ti.Matrix.zero(f, dim, dim)  # with_moment: sum_b V_b grad W_ib v_b^T
            # distances to the faces (inward), in the walls' order (x-, x+, y-, ...)
            dist = ti.Vector.zero(f, 2 * dim)
            near = False
            for a in ti.static(range(dim)):
                dist[2 * a] = xi[a] - lo[a]
                dist[2 * a + 1] = hi[a] - xi[a]
                if dist[2 * a] < h or dist[2 * a + 1] < h:
                    near = True
            # the colliders' lookups first: a free rigid body's limit (``hydrostatic``) is a pass over the
            # neighbour list, only for a particle that has a body in reach
            cres = [collider_at[c](xi) for c in ti.static(range(len(cols)))]
            lim = ti.cast(0.0, f)
            lim_body = ti.cast(0.0, f)
            if ti.static(with_hyd and any_rigid):
                reach = False
                for c in ti.static(range(len(cols))):
                    if ti.static(col_rigid[c]):
                        if cres[c][0] > 0:
                            reach = True
                if reach:
                    lim_body = body_limit(i)
                klim[i] = lim_body
            if near:
                for k in ti.static(range(2 * dim)):
                    ax, sgn, ns, vel = ti.static(faces[k][0], faces[k][2], faces[k][3], faces[k][4])
                    if dist[k] < h:
                        v = face_at(dist[k] * sF)
                        psi += v[0]
                        B[ax] += sgn * v[1]
                        cnt += v[2]
                        T += v[3]
                        if ti.static(any_vel[k]):
                            vw = ti.Vector(vel, dt=f)
                            S += sgn * vw[ax] * v[1]
                            if ti.static(with_moment):
                                Bf = ti.Vector.zero(f, dim)
                                Bf[ax] = sgn * v[1]
                                Q += Bf.outer_product(vw)
                        if ti.static(with_hyd or with_moment):
                            nv = ti.Vector.zero(f, dim)
                            nv[ax] = sgn
                            nn = nv.outer_product(nv)
                            Mo = v[6] * nn + v[7] * (ti.Matrix.identity(f, dim) - nn)
                            if ti.static(with_hyd):
                                Hy += hydrostatic(v[1] * nv, Mo, g, lim)
                            if ti.static(with_moment):
                                Mom += Mo
                        if ti.static(ns):
                            nv = ti.Vector.zero(f, dim)
                            nv[ax] = sgn
                            Mf = v[4] * nv.outer_product(nv) + v[5] * (
                                ti.Matrix.identity(f, dim) - nv.outer_product(nv)
                            )
                            M += Mf
                            if ti.static(any_vel[k]):
                                mw += Mf @ ti.Vector(vel, dt=f)
                # edges: the lattice beyond two faces of different axes was counted twice
                for k0 in ti.static(range(2 * dim)):
                    for k1 in ti.static(range(2 * dim)):
                        if ti.static(k0 // 2 < k1 // 2):
                            if dist[k0] < h and dist[k1] < h:
                                q = edge_at(dist[k0] * sE, dist[k1] * sE)
                                psi -= q[0]
                                B[k0 // 2] -= faces[k0][2] * q[1]
                                B[k1 // 2] -= faces[k1][2] * q[2]
                                cnt -= q[3]
                                T -= q[4]
                                if ti.static(with_hyd or with_moment):
                                    a0, a1 = ti.static(k0 // 2, k1 // 2)
                                    s0, s1 = ti.static(faces[k0][2], faces[k1][2])
                                    Mo = ti.Matrix.zero(f, dim, dim)
                                    Mo[a0, a0] = q[5]
                                    Mo[a1, a1] = q[6]
                                    Mo[a0, a1] = s0 * s1 * q[7]
                                    Mo[a1, a0] = s0 * s1 * q[7]
                                    if ti.static(dim == 3):
                                        a2 = ti.static(3 - a0 - a1)
                                        Mo[a2, a2] = q[8]
                                    Bo = ti.Vector.zero(f, dim)
                                    Bo[a0] = s0 * q[1]
                                    Bo[a1] = s1 * q[2]
                                    if ti.static(with_hyd):
                                        Hy -= hydrostatic(Bo, Mo, g, lim)
                                    if ti.static(with_moment):
                                        Mom -= Mo
                                if ti.static(faces[k1][3]):
                                    # no-slip: boundary particles give the edge's lattice the first face's
                                    # kind and velocity (boundary.wall_particles): the second face's copy goes
                                    a0, a1 = ti.static(k0 // 2, k1 // 2)
                                    s0, s1 = ti.static(faces[k0][2], faces[k1][2])
                                    Mq = ti.Matrix.zero(f, dim, dim)
                                    Mq[a0, a0] = q[9]
                                    Mq[a1, a1] = q[10]
                                    Mq[a0, a1] = s0 * s1 * q[11]
                                    Mq[a1, a0] = s0 * s1 * q[11]
                                    if ti.static(dim == 3):
                                        a2 = ti.static(3 - a0 - a1)
                                        Mq[a2, a2] = q[12]
                                    M -= Mq
                                    if ti.static(any_vel[k1]):
                                        mw -= Mq @ ti.Vector(faces[k1][4], dt=f)
                if ti.static(dim == 3):  # corners: counted three times, removed three times
                    for c in ti.static(range(8)):
                        k0, k1, k2 = ti.static(c & 1, 2 + ((c >> 1) & 1), 4 + ((c >> 2) & 1))
                        if dist[k0] < h and dist[k1] < h and dist[k2] < h:
                            o = corner_at(dist[k0] * sC, dist[k1] * sC, dist[k2] * sC)
                            psi += o[0]
                            B[0] += faces[k0][2] * o[1]
                            B[1] += faces[k1][2] * o[2]
                            B[2] += faces[k2][2] * o[3]
                            cnt += o[4]
                            T += o[5]
                            if ti.static(with_hyd or with_moment):
                                sg = ti.static((faces[k0][2], faces[k1][2], faces[k2][2]))
                                comps = ti.static(
                                    ((0, 0, 6), (1, 1, 7), (2, 2, 8), (0, 1, 9), (0, 2, 10), (1, 2, 11))
                                )
                                Mo = ti.Matrix.zero(f, dim, dim)
                                for m in ti.static(range(6)):
                                    i0, i1, ch = ti.static(comps[m])
                                    Mo[i0, i1] = sg[i0] * sg[i1] * o[ch]
                                    Mo[i1, i0] = sg[i0] * sg[i1] * o[ch]
                                Bo = ti.Vector([sg[0] * o[1], sg[1] * o[2], sg[2] * o[3]])
                                if ti.static(with_hyd):
                                    Hy += hydrostatic(Bo, Mo, g, lim)
                                if ti.static(with_moment):
                                    Mom += Mo
                            if ti.static(faces[k2][3]):  # no-slip: the third face's copy, removed twice
                                sg = ti.static((faces[k0][2], faces[k1][2], faces[k2][2]))
                                comps = ti.static(
                                    ((0, 0, 12), (1, 1, 13), (2, 2, 14), (0, 1, 15), (0, 2, 16), (1, 2, 17))
                                )
                                Mq = ti.Matrix.zero(f, dim, dim)
                                for m in ti.static(range(6)):
                                    i0, i1, ch = ti.static(comps[m])
                                    Mq[i0, i1] = sg[i0] * sg[i1] * o[ch]
                                    Mq[i1, i0] = sg[i0] * sg[i1] * o[ch]
                                M += Mq
                                if ti.static(any_vel[k2]):
                                    mw += Mq @ ti.Vector(faces[k2][4], dt=f)
            for c in ti.static(range(len(cols))):
                cpsi, cB, ccnt, cT, Mo, Mc, vs = cres[c]
                psi += cpsi
                B += cB
                cnt += ccnt
                T += cT
                if ti.static(col_moving[c]):  # the wall's velocity: the surface's at x_i (module docstring)
                    S += vs.dot(cB)
                    if ti.static(with_moment):
                        Q += cB.outer_product(vs)
                if ti.static(with_hyd):
                    Hy += hydrostatic(cB, Mo, g, lim_body if ti.static(col_rigid[c]) else lim)
                if ti.static(with_moment):
                    Mom += Mo
                if ti.static(col_noslip[c]):
                    M += Mc
                    if ti.static(col_moving[c]):
                        mw += Mc @ vs
            return psi, B, cnt, T, M, mw, S, Hy, Mom, Q

        def make_collider_terms(c):
            @ti.func
            def collider_terms(xi, g, i):
                """Collider map c's own B, hydrostatic term (zero unless with_hyd), no-slip matrix and surface
                velocity at liquid particle i at xi (the loads on a named collider), in the world frame (a
                rigid body's hydrostatic limit from i's density pass, ``boundary``)."""
                _psi, Bo, _cnt, _T, Mo, Mc, vs = collider_at[c](xi)
                Hc = ti.Vector.zero(f, dim)
                if ti.static(with_hyd):
                    lm = ti.cast(0.0, f)
                    if ti.static(col_rigid[c]):
                        lm = klim[i]
                    Hc = hydrostatic(Bo, Mo, g, lm)
                return Bo, Hc, Mc, vs

            return collider_terms

        self.collider_terms = [make_collider_terms(c) for c in range(len(cols))]
        return boundary

    def _make_body_limit(self, f, F, fn, wanted: bool):
        """``(body_limit(i) -> lim, klim)``: free rigid bodies' limit on the pull of their hydrostatic
        wall term (``hydrostatic``) for liquid particle i, the Shepard average of the liquid's last total k
        over i's neighbours and i (DFSPH: kappa, as wall_pressure.mark takes it; WCSPH: the particle's
        mirrored wall pressure / rho0), and the per-particle field that keeps it for the loads; a stub and
        None unless ``wanted`` (the extrapolated wall pressure with a rigid body's map)."""
        from simcli.backend import stdout_to_stderr

        with stdout_to_stderr():
            import taichi as ti

        if not wanted or F is None or fn is None:

            @ti.func
            def none(i):
                return ti.cast(0.0, f)

            return none, None
        klim = ti.field(f, shape=F.x.shape[0])
        self._body_limit = klim
        x, nb_cnt, nb_j = F.x, F.nb_cnt, F.nb_j
        W, volume_of = fn.Wk, fn.volume_of
        kap = F.kappa
        dfsph = kap is not None
        pw, mid, mat_rho0 = F.pw, F.mid, F.mat_rho0

        @ti.func
        def body_limit(i):
            lim = ti.cast(0.0, f)
            if ti.static(dfsph):
                xi = x[i]
                w0 = volume_of(i) * W(0.0)
                den = w0
                sk = w0 * kap[i]
                for k in range(nb_cnt[i]):
                    j = nb_j[i, k]
                    if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                        break
                    w = volume_of(j) * W((xi - x[j]).norm())
                    den += w
                    sk += w * kap[j]
                lim = ti.max(sk / den, 0.0)
            else:
                lim = ti.max(pw[i], 0.0) / mat_rho0[mid[i]]
            return lim

        return body_limit, klim

    @staticmethod
    def make_wall_k(F, fn):
        """Taichi func ``wall_k(i, k_) -> k_b``: the stiffness DFSPH's maps give the boundary next to liquid
        particle i, the Shepard average of the stiffness field ``k_`` over i's liquid neighbours and itself,
        sum_j V_j W_ij k_j / sum_j V_j W_ij (as boundary particles' extrapolated k, wall_pressure.py, is
        the Shepard average of the liquid's next to each boundary particle). Zero work for a particle with no
        boundary in reach (B_i = 0). Why not k_i itself (the mirror, session 9): with the mirror a particle
        next to a wall is pushed off it by 2 k_i, its own stiffness, which the solve raises wherever the
        particle is compressed; a DFSPH tank at rest then kept 3.5-4 cm/s of noise with wall particles
        kicked to 25-37 cm/s (docs/SPH.md, Gaps). Linear in ``k_``, so the iterations' increments add up to
        the average of the total."""
        from simcli.backend import stdout_to_stderr

        with stdout_to_stderr():
            import taichi as ti

        x, B, nb_cnt, nb_j = F.x, F.B, F.nb_cnt, F.nb_j
        W, volume_of = fn.Wk, fn.volume_of

        @ti.func
        def wall_k(i, k_):
            kb = k_[i] * 0.0
            if B[i].norm_sqr() > 0:
                xi = x[i]
                w0 = volume_of(i) * W(0.0)
                num = w0 * k_[i]
                den = w0
                for k in range(nb_cnt[i]):
                    j = nb_j[i, k]
                    if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                        break
                    w = volume_of(j) * W((xi - x[j]).norm())
                    num += w * k_[j]
                    den += w
                kb = num / den
            return kb

        return wall_k

    def make_loads(self, P, F, fn, poses):
        """Taichi funcs ``(pressure(i, dt), viscous(i, dt))`` that add the liquid's loads on the named
        colliders (static or moving, rigid bodies included) to ``poses`` (as moving.make_loads does with
        boundary particles): the impulse the collider's map gave liquid particle i this substep, reversed,
        applied at x_i. DFSPH: dt m_i (k_i L_i B_c + kb_i B_c + H_c) with the substep's total stiffness in
        F.kk (kb_i its Shepard average, make_wall_k, and the hydrostatic term with the extrapolated wall
        pressure, else Akinci's term alone); WCSPH: dt m_i rho0 p_i / rho_i^2 B_c (plus rho0 / rho_w^2 (p_w
        B_c + rho0 H_c) with the extrapolated wall pressure); no-slip: -dt m_i 2 (dim + 2) nu M_c (v_i -
        v_s), v_s the surface's velocity at x_i. Applied at x_i, not at the boundary points (the map has
        none), the moment is still the boundary particles' own: every pair force lies along x_i - x_b (grad
        W_ib is radial, also with the scalar gradient correction), so (x_b - c) x J_b = (x_i - c) x J_b."""
        from simcli.backend import stdout_to_stderr
        from simcli.solvers.sph.dfsph import BFAC

        with stdout_to_stderr():
            import taichi as ti

        f, dim = P.f, P.dim
        x, v, rho, p, mid, kk = F.x, F.v, F.rho, F.p, F.mid, F.kk
        mat_rho0, mat_nu, gravity, mat_k, mat_n, pw = F.mat_rho0, F.mat_nu, F.gravity, F.mat_k, F.mat_n, F.pw
        kgc, kgc_scalar, Lm, Lc = P.kgc, P.kgc_scalar, F.Lm, F.Lc
        dfsph = P.pressure_solver == "DFSPH"
        ext_map = F.Hb is not None
        named = self.named
        named_noslip = [c for c in named if self.colliders[c].no_slip] if P.has_noslip else []
        kidx = self.spec_index
        terms = self.collider_terms
        visc_c = 2.0 * (dim + 2)

        @ti.func
        def pressure(i, dt):
            xi = x[i]
            mi = fn.mass_of(i)
            for c in ti.static(named):
                Bo, Hc, _Mc, _vs = terms[c](xi, gravity[None], i)
                J = ti.Vector.zero(f, dim)
                if ti.static(dfsph):
                    gi = Bo
                    if ti.static(kgc_scalar):
                        gi = Lc[i] * Bo
                    elif ti.static(kgc):
                        gi = Lm[i] @ Bo
                    J = BFAC * kk[i] * gi  # as the velocity update (dfsph.py) and moving.py's loads
                    if ti.static(ext_map):
                        J += fn.map_wall_k(i, kk) * Bo + Hc
                    J *= dt * mi
                else:
                    ri = rho[i]
                    m = mid[i]
                    rho0 = mat_rho0[m]
                    J = (dt * mi * rho0 * p[i] / (ri * ri)) * Bo
                    if ti.static(ext_map):  # the mirrored, relaxing wall pressure (wcsph.py)
                        pb = pw[i]
                        rb = rho0 * ti.pow(ti.max(pb, 0.0) / mat_k[m] + 1.0, 1.0 / mat_n[m])
                        J += (dt * mi * rho0 / (rb * rb)) * (pb * Bo + rho0 * Hc)
                if J.norm_sqr() > 0:
                    poses.add_load(kidx[c], xi, J, 0)

        @ti.func
        def viscous(i, dt):
            if ti.static(len(named_noslip) > 0):
                xi = x[i]
                for c in ti.static(named_noslip):
                    _Bo, _Hc, Mc, vs = terms[c](xi, gravity[None], i)
                    # relative to the surface's velocity at x_i (zero for a static collider)
                    J = -dt * fn.mass_of(i) * visc_c * mat_nu[mid[i]] * (Mc @ (v[i] - vs))
                    if J.norm_sqr() > 0:
                        poses.add_load(kidx[c], xi, J, 0)

        return pressure, viscous
