"""The MPM operators built alone from a hand-made bundle (simcli/solvers/mpm/fields.py), without an
MPMSolver: the grid update (momentum -> velocity, gravity, boundary, empty nodes) and one P2G -> grid update
-> G2P round trip of a uniformly moving, unstressed 2D patch on a tiny grid (atomic P2G path)."""

import numpy as np
import pytest


def _bundle(ti, n, grid_shape, dx=0.1, origin=(-0.3, -0.3)):
    from simcli.solvers.mpm.fields import MPMFields, MPMParams

    dim, f = 2, ti.f32
    params = MPMParams(
        dim=dim,
        dtype=f,
        dx=dx,
        origin=origin,
        domain_lo=(0.0, 0.0),
        domain_hi=(1.0, 1.0),
        grid_shape=grid_shape,
        T=1,
        chunked=False,
        gdim=dim + 1,
        has_fixed=False,
        n_bodies=1,
    )
    fields = MPMFields(
        x=ti.Vector.field(dim, f, shape=n),
        v=ti.Vector.field(dim, f, shape=n),
        C=ti.Matrix.field(dim, dim, f, shape=n),
        F=ti.Matrix.field(dim, dim, f, shape=n),
        mass=ti.field(f, shape=n),
        vol=ti.field(f, shape=n),
        mid=ti.field(ti.i32, shape=n),
        fixed=None,
        pid=None,
        grid=ti.Vector.field(params.gdim, f, shape=(1,) + grid_shape),
        grid_v=ti.Vector.field(dim, f, shape=grid_shape),
        grid_m=ti.field(f, shape=grid_shape),
        bbox=ti.Vector.field(dim, ti.i32, shape=(1, 2)),
        bbox_all=ti.Vector.field(dim, ti.i32, shape=2),
        chunk_start=ti.field(ti.i32, shape=2),
        gravity=ti.Vector.field(dim, f, shape=()),
        mat_mu=ti.field(f, shape=1),
        mat_lam=ti.field(f, shape=1),
        mat_law_id=ti.field(ti.i32, shape=1),
        body_offsets=ti.field(ti.i32, shape=2),
        stat_speed=ti.field(f, shape=1),
        stat_bad=ti.field(ti.i32, shape=1),
        stat_stiff=ti.field(f, shape=()),
    )
    return params, fields


def _floor_boundary(ti, floor_node):
    """A stand-in for boundary.GridBoundary: a sticky floor below node row ``floor_node``, no colliders."""

    @ti.data_oriented
    class Floor:
        n_colliders = 0

        @ti.func
        def apply(self, I, v, m):
            r = v
            if I[1] < floor_node:
                r = ti.Vector.zero(ti.f32, 2)
            return r

    return Floor()


def test_grid_update_alone(ti_f32):
    import taichi as ti

    from simcli.solvers.mpm.grid_update import build_grid_update

    shape = (8, 8)
    params, fields = _bundle(ti, 1, shape)
    grid_update = build_grid_update(params, fields, _floor_boundary(ti, 3), None)

    @ti.kernel
    def run(dt: ti.f32):
        grid_update(dt)

    g = np.zeros((1,) + shape + (3,), np.float32)
    g[0, 4, 5] = [2.0, -1.0, 0.5]  # momentum (2, -1), mass 0.5: v = (4, -2)
    g[0, 2, 2] = [1.0, 1.0, 1.0]  # below the floor (row 3): stuck
    fields.grid.from_numpy(g)
    fields.bbox.from_numpy(np.array([[[1, 2], [6, 7]]], np.int32))  # node box [lo, hi)
    fields.gravity[None] = [0.0, -10.0]
    dt = 0.01
    run(dt)
    gv = fields.grid_v.to_numpy()
    assert gv[4, 5] == pytest.approx([4.0, -2.0 - 10.0 * dt], rel=1e-6)
    assert np.all(gv[2, 2] == 0.0)  # the boundary acts after gravity
    inside = np.zeros(shape, bool)
    inside[1:6, 2:7] = True
    inside[4, 5] = inside[2, 2] = False
    assert np.all(gv[inside] == 0.0)  # empty nodes of the box get no velocity
    assert fields.grid_m.to_numpy()[4, 5] == pytest.approx(0.5)
    assert fields.bbox_all.to_numpy().tolist() == [[1, 2], [6, 7]]


def test_p2g_grid_update_g2p_round_trip_alone(ti_f32):
    import taichi as ti

    from simcli.solvers.mpm.constitutive import NeoHookeanLaw
    from simcli.solvers.mpm.g2p import build_g2p
    from simcli.solvers.mpm.grid_update import build_grid_update
    from simcli.solvers.mpm.laws import build_law_dispatch
    from simcli.solvers.mpm.p2g import build_p2g
    from simcli.solvers.mpm.stencil import build_stencil

    n = 16
    shape = (16, 16)
    params, fields = _bundle(ti, n, shape)
    law = NeoHookeanLaw(2, ti.f32)
    law.allocate(n)
    dispatch = build_law_dispatch(
        2, ti.f32, [law], fields.mid, fields.mat_mu, fields.mat_lam, fields.mat_law_id
    )
    stencil = build_stencil(params)

    @ti.func
    def count():
        return n

    boundary = _floor_boundary(ti, 0)  # no node below row 0: no contact
    p2g = build_p2g(params, fields, stencil, dispatch.kirchhoff, None, count)
    grid_update = build_grid_update(params, fields, boundary, None)
    g2p = build_g2p(params, fields, stencil, [law], boundary, None, count)

    @ti.kernel
    def to_grid(dt: ti.f32):
        g2p.node_boxes()  # the node box P2G clears (from the initial positions)
        p2g.clear_grid()
        p2g.p2g(dt)

    @ti.kernel
    def substep_rest(dt: ti.f32):
        grid_update(dt)
        g2p.g2p(dt)

    rng = np.random.default_rng(3)
    x0 = rng.uniform(0.3, 0.6, size=(n, 2)).astype(np.float32)
    u = np.array([0.5, -0.25], np.float32)
    m = rng.uniform(0.5, 1.5, n).astype(np.float32)
    fields.x.from_numpy(x0)
    fields.v.from_numpy(np.broadcast_to(u, (n, 2)).copy())
    fields.mass.from_numpy(m)
    fields.vol.from_numpy(np.full(n, 1e-3, np.float32))
    fields.mat_mu.from_numpy(np.array([1e4], np.float32))
    fields.mat_lam.from_numpy(np.array([1e4], np.float32))
    fields.gravity[None] = [0.0, -10.0]
    dt = 1e-3
    to_grid(dt)
    g = fields.grid.to_numpy()[0].astype(np.float64)
    assert g[..., 2].sum() == pytest.approx(m.sum(), rel=1e-5)  # mass
    assert g[..., :2].reshape(-1, 2).sum(axis=0) == pytest.approx(m.sum() * u, rel=1e-5)  # momentum
    substep_rest(dt)
    v_new = u + dt * np.array([0.0, -10.0], np.float32)
    assert np.allclose(fields.v.to_numpy(), v_new, atol=1e-6)  # partition of unity, no stress at rest
    assert np.abs(fields.C.to_numpy()).max() < 1e-3
    assert np.allclose(fields.x.to_numpy(), x0 + dt * v_new, atol=1e-6)
