"""P2G, particle to grid (MLS-MPM, Hu et al. 2018, eq. 16 and 29), with the Kirchhoff stress fused in.

Each particle scatters ``w_i (m v + Q (x_i - x_p))`` to the 3^dim nodes of its quadratic B-spline stencil,
``Q = m C - dt V0 D^-1 tau`` (APIC; FLIP sends only the stress part, see transfer.py), plus its mass (and
the mass of fixed particles in their own channel).

On the CPU (``params.chunked``) particles are split into T contiguous chunks; chunk t clears and then
scatters into its own grid copy t with plain read-add-write (no atomics, bitwise reproducible for a given
thread count; see solver.py's module docstring). Elsewhere one grid copy with atomic adds.
"""

from dataclasses import dataclass
from typing import Any

from simcli.backend import stdout_to_stderr
from simcli.solvers.mpm.fields import CHUNK_STRIDE, MPMFields, MPMParams
from simcli.solvers.mpm.stencil import Stencil, chunk_of

with stdout_to_stderr():
    import taichi as ti


@dataclass(frozen=True)
class P2G:
    """``clear_grid()``: zero the grid copy (atomic path; the chunked path clears inside ``p2g``);
    ``p2g(dt)``: scatter every particle. Both are ``ti.func``: call them from a kernel."""

    clear_grid: Any
    p2g: Any


def build_p2g(
    params: MPMParams,
    fields: MPMFields,
    stencil: Stencil,
    kirchhoff,
    flip,
    count,
    chunk_clear=None,
    cpic=None,
) -> P2G:
    """``kirchhoff(p, F, J, update)``: the particle's Kirchhoff stress (laws.LawDispatch.kirchhoff);
    ``flip``: the FLIP transfer (transfer.FlipTransfer) or None (APIC); ``count``: ti.func, the particle
    loop's bound; ``chunk_clear(t)``: with the block list and chunks, zeroes copy t in chunk t's task
    (blocks.py); ``cpic``: cpic.CPIC or None (a particle sends nothing to the nodes across a CPIC
    collider). Reads x, v, C, F, mass, vol, fixed, bbox, chunk_start; writes grid."""
    use_cpic = cpic is not None
    dim, f, T, gdim, gap_ch = params.dim, params.dtype, params.T, params.gdim, params.gap_ch
    gap_aff = params.gap_aff
    chunked, has_fixed = params.chunked, params.has_fixed
    dx, inv_dx = params.dx, params.inv_dx
    N = count
    x, v, C, F, mass, vol, fixed = (
        fields.x,
        fields.v,
        fields.C,
        fields.F,
        fields.mass,
        fields.vol,
        fields.fixed,
    )
    grid, bbox, chunk_start = fields.grid, fields.bbox, fields.chunk_start
    own_clear = chunk_clear is not None
    use_flip = flip is not None
    bspline, cols = stencil.bspline, stencil.cols

    @ti.func
    def node_value(val, weight, m, fm, mv, xp, aff):
        c = ti.Vector.zero(f, gdim)
        if ti.static(gap_ch >= 0):  # the material's position (the frictional colliders' gap test)
            for d in ti.static(range(dim)):
                c[gap_ch + d] = weight * m * xp[d]
        if ti.static(gap_aff):  # its affine momentum m C (x_i - x_p) (APIC), see boundary._node
            for d in ti.static(range(dim)):
                c[gap_ch + dim + d] = weight * aff[d]
        for d in ti.static(range(dim)):
            c[d] = weight * val[d]
        c[dim] = weight * m
        if ti.static(has_fixed):
            c[dim + 1] = weight * fm
        if ti.static(use_flip):  # FLIP: the momentum without the stress impulse too
            c = flip.momentum(c, weight, mv)
        return c

    @ti.func
    def p2g_particle(p, t, dt):
        base, fx, w = bspline(x[p])
        Fp = ti.Matrix.identity(f, dim) + F[p]  # F stores H = F - I
        J = Fp.determinant()
        tau = kirchhoff(p, Fp, J, True)
        m = mass[p]
        # MLS-MPM (Hu et al. 2018, eq. 16 and 29): node i gets w_i (m v + Q (x_i - x_p)) with
        # Q = m C - dt V0 D^-1 tau, D^-1 = 4 / dx^2 for quadratic B-splines; x_i - x_p = (i - fx) dx
        affine = (-dt * vol[p] * 4.0 * inv_dx * inv_dx) * tau
        if ti.static(not use_flip):  # APIC sends the affine velocity C; FLIP only the stress
            affine = affine + m * C[p]
        mv = m * v[p]
        q0 = mv - affine @ (fx * dx)
        A = cols(affine * dx)
        mC = ti.Matrix.zero(f, dim, dim)
        if ti.static(gap_aff):
            mC = m * C[p]
        a0 = -mC @ (fx * dx)
        Ac = cols(mC * dx)
        fm = 0.0
        if ti.static(has_fixed):
            fm = m * ti.cast(fixed[p], f)
        mask = 0
        if ti.static(use_cpic):  # the stencil nodes across a CPIC collider get nothing (cpic.py)
            mask, W, M1, _vg, jj = cpic.classify(x[p], fx, v[p])
            if jj >= 0:  # the momentum sent across: the collider's until G2P takes it back (cpic.py)
                cpic.add_load(jj, x[p], W * mv + affine @ (M1 * dx))
        for i in ti.static(range(3)):
            qi = q0 + A[0] * i
            ai = a0 + Ac[0] * i
            wi = w[i][0]
            for j in ti.static(range(3)):
                qij = qi + A[1] * j
                aij = ai + Ac[1] * j
                wij = wi * w[j][1]
                if ti.static(dim == 2):
                    c = ti.Vector.zero(f, gdim)
                    if ti.static(use_cpic):  # across a CPIC collider: to the node's ghost channels
                        kp = cpic.keep(mask, i * 3 + j)
                        c = cpic.ghost(
                            node_value(qij, wij * kp, m, fm, mv, x[p], aij), qij, wij * (1 - kp), m
                        )
                    else:
                        c = node_value(qij, wij, m, fm, mv, x[p], aij)
                    if ti.static(chunked):  # chunk t owns copy t: plain read-add-write
                        grid[t, base[0] + i, base[1] + j] = grid[t, base[0] + i, base[1] + j] + c
                    else:
                        grid[0, base[0] + i, base[1] + j] += c
                else:
                    for k in ti.static(range(3)):
                        c = ti.Vector.zero(f, gdim)
                        if ti.static(use_cpic):
                            wk = wij * w[k][2]
                            kp = cpic.keep(mask, i * 9 + j * 3 + k)
                            qk = qij + A[2] * k
                            c = cpic.ghost(
                                node_value(qk, wk * kp, m, fm, mv, x[p], aij + Ac[2] * k),
                                qk,
                                wk * (1 - kp),
                                m,
                            )
                        else:
                            c = node_value(qij + A[2] * k, wij * w[k][2], m, fm, mv, x[p], aij + Ac[2] * k)
                        if ti.static(chunked):
                            grid[t, base[0] + i, base[1] + j, base[2] + k] = (
                                grid[t, base[0] + i, base[1] + j, base[2] + k] + c
                            )
                        else:
                            grid[0, base[0] + i, base[1] + j, base[2] + k] += c

    @ti.func
    def clear_copy(t):
        """Zero copy t of the grid over the node box of chunk t (the nodes p2g will write)."""
        a = bbox[t, 0]
        b = bbox[t, 1]
        if ti.static(dim == 3):
            for i, j, k in ti.ndrange((a[0], b[0]), (a[1], b[1]), (a[2], b[2])):
                grid[t, i, j, k] = ti.Vector.zero(f, gdim)
        else:
            for i, j in ti.ndrange((a[0], b[0]), (a[1], b[1])):
                grid[t, i, j] = ti.Vector.zero(f, gdim)

    @ti.func
    def clear_grid():
        # chunked (CPU): each chunk clears its own copy at the start of its p2g task, see p2g
        if ti.static(not chunked and not params.block_list):  # block list: blocks.py clears
            clear_copy(0)

    @ti.func
    def p2g(dt):
        if ti.static(chunked):
            for j in range(T * CHUNK_STRIDE):
                t = chunk_of(j)
                if t >= 0:
                    if ti.static(own_clear):  # the block list's (blocks.py)
                        chunk_clear(t)
                    elif ti.static(not params.block_list):
                        clear_copy(t)  # serial inside the chunk's task: saves a parallel launch
                    for p in range(chunk_start[t], chunk_start[t + 1]):
                        p2g_particle(p, t, dt)
        else:
            for p in range(N()):
                p2g_particle(p, 0, dt)

    return P2G(clear_grid, p2g)
