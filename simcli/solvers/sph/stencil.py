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
