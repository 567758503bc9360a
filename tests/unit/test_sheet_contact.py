"""The MPM <-> cloth contact of the coupling phase (simcli/coupling/sheet_contact.py) on its own: a small 2D
MPM grid holding a block of material, points (cloth vertices) around its right face, one coupling call.
Points that ended a substep inside the material come out onto its surface on the side they came from, points
outside are left alone, and the momentum the points gain is the momentum MPM's nodes lose."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

DX = 0.1
FACE = 0.8  # the block's right face: MPM particles on a lattice of spacing DX / 2 over x in [0.4, 0.8]
_BUILT: dict = {}


def _build(ti):
    from simcli.coupling.sheet_contact import SheetContact

    dim, f = 2, ti.f32
    shape = (16, 16)
    g = np.meshgrid(np.arange(0.4, FACE, 0.05) + 0.025, np.arange(0.4, 1.2, 0.05) + 0.025, indexing="ij")
    xm = np.column_stack([g[0].ravel(), g[1].ravel()])
    n_m = len(xm)
    mpm = SimpleNamespace(
        dim=dim,
        f=f,
        grid_shape=shape,
        precision="f32",
        dx=DX,
        inv_dx=1.0 / DX,
        origin=np.zeros(2),
        lo_node=(1, 1),
        hi_node=(14, 14),
        flip=None,
        store_node_mass=False,
    )
    mpm.grid_v = ti.Vector.field(dim, f, shape=shape)
    mpm.grid_m = ti.field(f, shape=shape)
    mpm.bbox_all = ti.Vector.field(dim, ti.i32, shape=2)
    mpm.x = ti.Vector.field(dim, f, shape=n_m)
    mpm.F = ti.Matrix.field(dim, dim, f, shape=n_m)
    mpm.vol = ti.field(f, shape=n_m)

    @ti.func
    def count():
        return n_m

    mpm.count = count
    mpm.x.from_numpy(xm.astype(np.float32))
    mpm.vol.from_numpy(np.full(n_m, 0.05**2, np.float32))
    gm = np.zeros(shape)  # the node masses MPM's P2G leaves (density 500)
    for p in xm:
        X = p / DX
        b = (X - 0.5).astype(int)
        fx = X - b
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
        for i in range(3):
            for j in range(3):
                gm[b[0] + i, b[1] + j] += w[i][0] * w[j][1] * (500.0 * 0.05**2)
    mpm.grid_m.from_numpy(gm.astype(np.float32))
    mpm.bbox_all.from_numpy(np.array([[1, 1], [15, 15]], np.int32))

    n = 5
    x = ti.Vector.field(3, f, shape=n)  # PBD keeps 3 components in 2D
    xp = ti.Vector.field(3, f, shape=n)
    v = ti.Vector.field(3, f, shape=n)
    m_f = ti.field(f, shape=n)

    @ti.func
    def mass(i):
        return m_f[i]

    sc = SheetContact(mpm, "test")
    sc.build(n, mass, x, xp, v)
    assert mpm.store_node_mass  # the contact asks MPM to keep its node masses
    return {"sc": sc, "mpm": mpm, "gm": gm, "x": x, "xp": xp, "v": v, "m": m_f}


def _run(ti, start, end, vel, masses, grid_v=(0.0, 0.0), dt=1e-3):
    if "sc" not in _BUILT:
        _BUILT.update(_build(ti))
    b = SimpleNamespace(**_BUILT)
    gv = np.zeros(b.gm.shape + (2,))
    gv[b.gm > 0] = grid_v
    b.mpm.grid_v.from_numpy(gv.astype(np.float32))
    pad = lambda a: np.column_stack([np.asarray(a, float), np.zeros(len(a))]).astype(np.float32)  # noqa: E731
    b.xp.from_numpy(pad(start))
    b.x.from_numpy(pad(end))
    b.v.from_numpy(pad(vel))
    b.m.from_numpy(np.asarray(masses, np.float32))
    b.sc.couple(dt)
    return b, gv


def _phi(xy):
    """The block's volume fraction at xy as the contact sees it (splat, then B-spline interpolation)."""
    b = SimpleNamespace(**_BUILT)
    xm = b.mpm.x.to_numpy().astype(np.float64)
    node = np.zeros(b.gm.shape)
    for p in xm:
        X = p / DX
        i0 = (X - 0.5).astype(int)
        fx = X - i0
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
        for i in range(3):
            for j in range(3):
                node[i0[0] + i, i0[1] + j] += w[i][0] * w[j][1] * 0.05**2 / DX**2
    X = np.asarray(xy) / DX
    i0 = (X - 0.5).astype(int)
    fx = X - i0
    w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
    return sum(w[i][0] * w[j][1] * node[i0[0] + i, i0[1] + j] for i in range(3) for j in range(3))


@pytest.mark.parametrize("grid_v", [(0.0, 0.0), (-0.5, 0.3)])
def test_points_inside_come_out_and_momentum_is_conserved(ti_f32, grid_v):
    import taichi as ti

    dt = 1e-3
    # the body's frame: a point ends at x_end, the material moved grid_v dt, so it is at x_end - grid_v dt
    start = [[0.85, 0.60], [0.83, 0.70], [0.86, 0.80], [0.95, 0.90], [0.90, 1.00]]
    end = [[0.77, 0.60], [0.74, 0.70], [0.86, 0.80], [0.95, 0.90], [0.70, 1.00]]
    vel = [[-80.0, 0.0], [-90.0, 0.0], [0.0, 0.0], [0.0, 0.0], [-200.0, 0.0]]
    masses = [0.01, 0.01, 0.01, 0.01, 0.0]  # the last one is pinned: not coupled
    b, gv = _run(ti, start, end, vel, masses, grid_v, dt)
    x1 = b.x.to_numpy()[:, :2].astype(np.float64)
    v1 = b.v.to_numpy()[:, :2].astype(np.float64)
    frame = x1 - np.asarray(grid_v) * dt
    for i in (0, 1):  # came in: out again, onto the surface (phi = 1/2), not past it
        assert _phi(frame[i]) <= 0.5 + 1e-3, (i, frame[i], _phi(frame[i]))
        assert frame[i][0] > FACE - 0.01 and frame[i][0] < FACE + 0.02, frame[i]
        assert abs(x1[i][1] - end[i][1]) < 0.02 * DX  # free slip: the tangential position is kept
    assert np.allclose(x1[2:], np.asarray(end)[2:], atol=1e-6)  # outside, and the pinned one: left alone
    assert np.allclose(v1[2:], np.asarray(vel)[2:], atol=1e-6)
    # position and velocity stay consistent: the move is dt times the velocity change
    assert np.allclose(x1 - np.asarray(end), dt * (v1 - np.asarray(vel)), atol=1e-5)
    gv1 = b.mpm.grid_v.to_numpy().astype(np.float64)
    p_mpm = (b.gm[..., None] * (gv1 - gv)).sum(axis=(0, 1))
    p_pts = (np.asarray(masses)[:, None] * (v1 - np.asarray(vel))).sum(axis=0)
    assert p_pts[0] > 0.5  # the points were pushed back out (+x)
    assert np.abs(p_mpm + p_pts).max() < 1e-5 * np.abs(p_pts).max()  # MPM took the reaction


def test_a_point_that_crossed_deep_goes_back_to_its_side(ti_f32):
    """A vertex that started outside the right face and ended near the left one (a large step): the nearest
    surface is the left face, but a sheet keeps its side: back where its path entered, on the right."""
    import taichi as ti

    dt = 1e-3
    b, gv = _run(
        ti,
        [[0.85, 0.8], [0.9, 0.5], [0.9, 0.6], [0.9, 0.7], [0.9, 0.9]],
        [[0.45, 0.8], [0.9, 0.5], [0.9, 0.6], [0.9, 0.7], [0.9, 0.9]],
        [[-400.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]],
        [0.001, 0.001, 0.001, 0.001, 0.001],
        (0.0, 0.0),
        dt,
    )
    x1 = b.x.to_numpy()[0, :2]
    assert FACE - 0.01 < x1[0] < FACE + 0.02, x1  # not out of the left face (x = 0.4)
    assert np.allclose(b.x.to_numpy()[1:, :2], [[0.9, 0.5], [0.9, 0.6], [0.9, 0.7], [0.9, 0.9]])


def test_the_set_relaxes_only_when_a_point_touched(ti_f32):
    """The extra constraint sweeps between pushes (relax) run only in a substep where a point was pushed: a
    cloth that touches nothing steps exactly as PBD alone."""
    import taichi as ti

    from simcli.coupling.sheet_contact import RELAX

    calls = []
    outside = [[0.9, 0.5], [0.9, 0.6], [0.9, 0.7], [0.9, 0.8], [0.9, 0.9]]
    if "sc" not in _BUILT:
        _BUILT.update(_build(ti))
    _BUILT["sc"].relax = calls.append
    try:
        b, gv = _run(ti, outside, outside, [[0.0, 0.0]] * 5, [0.01] * 5)
        assert calls == []
        assert np.allclose(b.mpm.grid_v.to_numpy(), gv.astype(np.float32))
        assert np.allclose(b.x.to_numpy()[:, :2], outside)
        inside = [[0.77, 0.5]] + outside[1:]
        b, gv = _run(ti, outside, inside, [[-130.0, 0.0]] + [[0.0, 0.0]] * 4, [0.01] * 5)
        assert len(calls) == RELAX
    finally:
        _BUILT["sc"].relax = None
