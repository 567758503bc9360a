"""The cell stencil and per-particle constants every SPH pass shares: ``rows`` / ``row_cell`` walk the
(2 R + 1)^dim cells around a point as rows of contiguous cells, ``mass_of`` / ``volume_of`` give a
particle's mass and rest volume (compile-time constants with one material)."""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams

with stdout_to_stderr():
    import taichi as ti


def make_stencil(P: SPHParams, F: SPHFields, fn: SPHFuncs):
    """``(rows, row_cell, mass_of, volume_of)``; needs ``fn.cell_coords`` and ``fn.linear``."""
    dim, f, R = P.dim, P.f, P.R
    mass, mid, mat_rho0 = F.mass, F.mid, F.mat_rho0
    cell_coords, linear = fn.cell_coords, fn.linear
    c_lo = ti.Vector([R] * dim)
    c_hi = ti.Vector([d - 1 - R for d in P.grid_dims])
    row = 2 * R + 1
    uniform = P.uniform
    m_c = P.m_c
    V_c = P.V_c

    @ti.func
    def mass_of(j):
        """Particle mass [kg]: a compile-time constant with one material (saves a load per neighbour)."""
        m = ti.cast(m_c, f)
        if ti.static(not uniform):
            m = mass[j]
        return m

    @ti.func
    def volume_of(j):
        """Rest volume m_j / rho0_j [m^dim]."""
        V = ti.cast(V_c, f)
        if ti.static(not uniform):
            V = mass[j] / mat_rho0[mid[j]]
        return V

    @ti.func
    def rows(xi):
        """Cell coordinates of the first cell of the central row of cells around xi (clamped so that
        every row stays inside the grid)."""
        c = ti.min(ti.max(cell_coords(xi), c_lo), c_hi)
        c[0] -= R
        return c

    @ti.func
    def row_cell(c0, a):
        """Linear index of the first cell of row a (0 <= a < row^(dim - 1)) of the stencil that starts at
        c0 (from rows): a row is `row` cells contiguous along x."""
        c = c0
        c[1] += a % row - R
        if ti.static(dim == 3):
            c[2] += a // row - R
        return linear(c)

    return rows, row_cell, mass_of, volume_of


def make_row_span(P: SPHParams, fn: SPHFuncs):
    """``row_span(xq, c0, a) -> (l0, l1)``: the cells [l0, l1) (linear indices) of row a of the stencil that
    starts at c0 (``rows``, ``row_cell``) that can hold a point closer than the support radius h to xq.

    The (2 R + 1)^dim stencil of cells of size h / R covers a cube of side (2 R + 1) h / R around a point,
    2.7x (R = 2) the volume of its support sphere. A row is skipped when its distance from xq across the
    other axes is h or more (the corner rows, mostly), and the cells at a row's ends are cut where the
    sphere's chord ends. Only points at a distance of h or more are left out, which the callers' test
    r^2 < h^2 rejects anyway, and the order of the rest is unchanged: the neighbour lists and every sum are
    bitwise those of the whole stencil (conservative by a margin of 1e-3 cells against the rounding of the
    cell assignment; the grid's outermost cells, which hold the points clamped into the grid, are never
    cut on their outer side). Without ``P.grid_origin`` / ``P.grid_cell`` the whole row."""
    dim, f, R = P.dim, P.f, P.R
    row = 2 * R + 1
    row_cell = fn.row_cell
    trim = P.grid_origin is not None and P.grid_cell is not None
    cell = float(P.grid_cell) if trim else 1.0
    m = 1e-3 * cell
    hm2 = (P.h + m) ** 2
    inv_cell = 1.0 / cell
    org = tuple(P.grid_origin) if trim else (0.0,) * dim
    dims = tuple(P.grid_dims)

    @ti.func
    def gap(xa, ca, o: ti.template(), nd: ti.template()):
        """Distance of the coordinate xa from the slab of cells ca along one axis (0 inside it)."""
        g = ti.cast(0.0, f)
        lo = ti.cast(o - m, f) + ca * ti.cast(cell, f)
        hi = ti.cast(o + m, f) + (ca + 1) * ti.cast(cell, f)
        if ca > 0 and xa < lo:
            g = lo - xa
        if ca < nd - 1 and xa > hi:
            g = xa - hi
        return g

    @ti.func
    def row_span(xq, c0, a):
        l0 = row_cell(c0, a)
        l1 = l0 + row
        if ti.static(trim):
            gy = gap(xq[1], c0[1] + a % row - R, org[1], dims[1])
            rho2 = gy * gy
            if ti.static(dim == 3):
                gz = gap(xq[2], c0[2] + a // row - R, org[2], dims[2])
                rho2 += gz * gz
            if rho2 >= hm2:
                l1 = l0
            else:
                ex = ti.sqrt(hm2 - rho2)
                k0 = ti.cast(ti.floor((xq[0] - ex - org[0]) * inv_cell), ti.i32) - c0[0]
                k1 = ti.cast(ti.floor((xq[0] + ex - org[0]) * inv_cell), ti.i32) - c0[0]
                if c0[0] == 0:  # the grid's first cell: it holds the points clamped below the grid
                    k0 = 0
                if c0[0] + row == dims[0]:  # the last cell: points clamped above the grid
                    k1 = row - 1
                k0 = ti.max(k0, 0)
                k1 = ti.min(k1, row - 1)
                if k1 < k0:
                    l1 = l0
                else:
                    l1 = l0 + k1 + 1
                    l0 += k0
        return l0, l1

    return row_span
