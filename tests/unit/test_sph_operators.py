"""WCSPH and DFSPH built alone from a hand-made bundle (simcli/solvers/sph/bundle.py), without an SPHSolver:
a 7 x 7 lattice of liquid particles in 2D, no walls, no gravity, no viscosity.

* Compressed to 95% of the spacing, one substep pushes the liquid apart: every particle moves away from
  the centre or stays, the centre particle stays (symmetry), the velocities are mirror-symmetric, and the
  pair forces conserve momentum.
* At the rest spacing the interior particles sit at rest density and the liquid stays at rest through a
  substep (zero pressure force, zero divergence).
"""

import numpy as np
import pytest

PS = 0.05  # particle size [m]
RHO0 = 1000.0
SIDE = 7  # particles per side
DT = 1.0e-3


def _params(solver: str, f, grid, n: int):
    from simcli.solvers.sph.bundle import SPHParams
    from simcli.solvers.sph.kernels import lattice_sum
    from simcli.solvers.sph.neighbours import neighbour_capacity

    V = PS**2 / lattice_sum(2.0, 2)
    return SPHParams(
        dim=2,
        f=f,
        n=n,
        ps=PS,
        h=2.0 * PS,
        K=neighbour_capacity(2, 2.0),
        R=grid.R,
        grid_dims=tuple(grid.dims),
        domain_lo=(0.0, 0.0),
        domain_hi=(0.6, 0.6),
        nbp=0,
        uniform=True,
        m_c=RHO0 * V,
        V_c=V,
        pressure_solver=solver,
        store_grad=solver == "DFSPH",
        has_viscosity=False,
        has_tension=False,
        has_noslip=False,
        shifting=0.0,
        viscosity_operator="monaghan",
        kgc=False,
        kgc_scalar=False,
        ext_walls=False,
        moving_boundary=False,
        named_loads=False,
        clamp_pressure=True,
        background_pressure=0.0,
        wall_pressure_relaxation=0.2,
        warm_start=False,
        divergence_solve=True,
        max_divergence_error_percent=0.1,
        max_density_error_percent=0.01,
        max_divergence_iterations=100,
        max_density_iterations=200,
        cpu=True,
    )


def _build(solver: str):
    """(step, P, F, fn): ``step(x0)`` loads the lattice x0 at rest, runs one substep and returns (x, v, rho)
    in entity order."""
    import taichi as ti

    from simcli.solvers.sph.advect import make_advect
    from simcli.solvers.sph.bundle import SPHFields, SPHFuncs
    from simcli.solvers.sph.density import make_neighbours_density
    from simcli.solvers.sph.dfsph import SolveStats, make_dfsph
    from simcli.solvers.sph.kernels import make_kernels
    from simcli.solvers.sph.neighbours import CellGrid, make_neighbour_funcs
    from simcli.solvers.sph.non_pressure import make_non_pressure
    from simcli.solvers.sph.outputs import make_outputs
    from simcli.solvers.sph.stencil import make_stencil
    from simcli.solvers.sph.wcsph import make_wcsph

    f, n = ti.f32, SIDE * SIDE
    grid = CellGrid(np.zeros(2), np.full(2, 0.6), 2.0 * PS, 2)
    P = _params(solver, f, grid, n)
    dfsph = P.dfsph
    vec = lambda: ti.Vector.field(2, f, shape=n)  # noqa: E731
    scal = lambda: ti.field(f, shape=n)  # noqa: E731
    F = SPHFields(
        x=vec(),
        v=vec(),
        vnew=vec(),
        mass=scal(),
        rho=scal(),
        p=scal(),
        mid=ti.field(ti.i32, shape=n),
        pid=ti.field(ti.i32, shape=n),
        B=vec(),
        Sb=scal(),
        nb_cnt=ti.field(ti.i32, shape=n),
        nbb_cnt=ti.field(ti.i32, shape=n),
        nb_j=ti.field(ti.i32, shape=(n, P.K)),
        nb_s=ti.field(f, shape=(n, P.K)) if dfsph else None,
        nrm=None,
        Mv=None,
        mw=None,
        shift=None,
        alpha=scal() if dfsph else None,
        nbw_end=None,
        bflag=None,
        Lm=None,
        Lc=None,
        kk=scal() if dfsph else None,
        kacc=scal() if dfsph else None,
        kappa=scal() if dfsph else None,
        kappav=scal() if dfsph else None,
        err_acc=ti.field(ti.i64, shape=()),
        overflow=ti.field(ti.i32, shape=()),
        start=ti.field(ti.i32, shape=grid.ncells + 1),
        bx=ti.Vector.field(2, f, shape=1),
        bV=ti.field(f, shape=1),
        bvel=ti.Vector.field(2, f, shape=1),
        bns=ti.field(ti.i32, shape=1),
        bstart=ti.field(ti.i32, shape=grid.ncells + 1),
        bnear=ti.field(ti.i8, shape=grid.ncells),
        bx0=None,
        bcol=None,
        mat_rho0=ti.field(f, 1),
        mat_k=ti.field(f, 1),
        mat_n=ti.field(f, 1),
        mat_nu=ti.field(f, 1),
        mat_gamma=ti.field(f, 1),
        gravity=ti.Vector.field(2, f, shape=()),
        body_offsets=ti.field(ti.i32, shape=2),
        stat_speed=ti.field(f, shape=1),
        stat_bad=ti.field(ti.i32, shape=1),
        stat_dt=ti.field(f, shape=2),
    )
    move = [F.x, F.v, F.mass, F.mid, F.pid] + ([F.kappa, F.kappav] if dfsph else [])
    sort, cell_coords, linear = make_neighbour_funcs(
        grid,
        f,
        True,
        {
            "x": F.x,
            "move": move,
            "move_tmp": [_twin(ti, fld) for fld in move],
            "cell_id": ti.field(ti.i32, shape=n),
            "rank": ti.field(ti.i32, shape=n),
            "count": ti.field(ti.i32, shape=grid.ncells),
            "start": F.start,
            "block_sum": ti.field(ti.i32, shape=grid.nblocks),
        },
    )

    @ti.func
    def count():
        return n

    @ti.func
    def no_colliders(xi, vi):
        return xi, vi

    fn = SPHFuncs(count=count, sort=sort, cell_coords=cell_coords, linear=linear, pushout=no_colliders)
    fn.Wk, fn.gradW, fn.Ckern, fn.W_gradW = make_kernels(P.h, 2, f)
    fn.rows, fn.row_cell, fn.mass_of, fn.volume_of = make_stencil(P, F, fn)
    fn.neighbours_density = make_neighbours_density(P, F, fn)
    fn.non_pressure = make_non_pressure(P, F, fn)
    fn.advect = make_advect(P, F, fn)
    _, density_only, _ = make_outputs(P, F, fn, 1)
    if dfsph:
        substep, phases = make_dfsph(P, F, fn, SolveStats(), lambda: n)
    else:
        substep, _, phases = make_wcsph(P, F, fn)
    assert phases[2] is (F.v if dfsph else F.vnew)  # the velocity a coupling phase edits

    for fld, val in (
        (F.mat_rho0, RHO0),
        (F.mat_k, 5.0e4),
        (F.mat_n, 7.0),
        (F.mat_nu, 0.0),
        (F.mat_gamma, 0.0),
    ):
        fld.from_numpy(np.array([val], np.float32))
    F.gravity[None] = [0.0, 0.0]
    F.body_offsets.from_numpy(np.array([0, n], np.int32))

    def step(x0: np.ndarray):
        F.x.from_numpy(x0.astype(np.float32))
        F.v.fill(0)
        F.mass.fill(P.m_c)
        F.mid.fill(0)
        F.pid.from_numpy(np.arange(n, dtype=np.int32))
        if dfsph:
            F.kappa.fill(0)
            F.kappav.fill(0)
        density_only()
        rho = np.empty(n)
        rho[F.pid.to_numpy()] = F.rho.to_numpy()
        substep(DT)
        pid = F.pid.to_numpy()
        x, v = np.empty((n, 2)), np.empty((n, 2))
        x[pid], v[pid] = F.x.to_numpy(), F.v.to_numpy()
        return x, v, rho

    return step


def _twin(ti, fld):
    """A field of the same kind and shape (the sort's temporary)."""
    if isinstance(fld, ti.MatrixField):
        return ti.Vector.field(fld.n, fld.dtype, shape=fld.shape)
    return ti.field(fld.dtype, shape=fld.shape)


def _lattice(spacing: float) -> np.ndarray:
    ax = 0.3 + spacing * (np.arange(SIDE) - (SIDE - 1) / 2)
    gx, gy = np.meshgrid(ax, ax, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


@pytest.mark.parametrize("solver", ["WCSPH", "DFSPH"])
def test_pressure_step_alone_keeps_rest_and_pushes_a_compressed_lattice_apart(ti_f32, solver):
    step = _build(solver)
    idx = np.arange(SIDE * SIDE).reshape(SIDE, SIDE)
    interior = idx[2:-2, 2:-2].ravel()  # full support (2 particle sizes)
    centre = idx[SIDE // 2, SIDE // 2]

    # compressed: pushed apart, symmetrically, momentum conserved
    x0 = _lattice(0.95 * PS)
    x, v, rho = step(x0)
    assert rho[centre] > 1.05 * RHO0
    speed = np.linalg.norm(v, axis=1)
    vmax = speed.max()
    assert vmax > 1e-3
    r = x0 - 0.3
    assert np.all(np.einsum("ij,ij->i", v, r) >= -1e-5 * vmax)  # outward or still
    assert speed[centre] < 1e-5 * vmax
    assert np.abs(v.sum(axis=0)).max() < 1e-4 * vmax * len(v)  # equal masses: the sum of velocities
    vg = v.reshape(SIDE, SIDE, 2)
    assert np.allclose(vg[::-1, :, 0], -vg[:, :, 0], atol=1e-5 * vmax)  # mirror x -> -x
    assert np.allclose(vg[::-1, :, 1], vg[:, :, 1], atol=1e-5 * vmax)
    assert np.allclose(vg.transpose(1, 0, 2)[..., ::-1], vg, atol=1e-5 * vmax)  # swap x and y

    # at rest spacing: rest density inside, nothing moves (to f32 round-off of rho / rho0 = 1, which DFSPH
    # turns into a velocity of error x h / dt)
    x0 = _lattice(PS)
    x, v, rho = step(x0)
    assert np.allclose(rho[interior], RHO0, rtol=1e-5)
    assert np.all(rho <= RHO0 * (1 + 1e-5))  # the edges are under-dense: no pressure there either
    assert np.abs(v).max() < 1e-4 * vmax
    assert np.allclose(x, x0, atol=1e-7)
