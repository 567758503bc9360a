"""The MPM grid contact of the coupling phase (simcli/coupling/grid_contact.py) on its own: a small MPM grid
and a particle set with random states, one coupling call. Momentum given to MPM's nodes plus momentum given to
the particles is zero, kinetic energy does not grow, and approaching materials stop approaching."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

_BUILT: dict = {}


def _setup(ti, seed, approach=True):
    """The contact (built and compiled once per session) with fresh random velocities."""
    rng = np.random.default_rng(seed)
    if "gc" not in _BUILT:
        _BUILT.update(_build(ti))
    b = SimpleNamespace(**_BUILT)
    gv = rng.normal(0.0, 0.3, b.gm.shape + (2,))
    if approach:
        gv[..., 0] += 1.0  # MPM moving right, into the other set
    gv[b.gm == 0] = 0.0
    b.mpm.grid_v.from_numpy(gv.astype(np.float32))
    b.xo_f.from_numpy(b.xo.astype(np.float32))  # the overlap correction may have moved them
    vo = rng.normal(0.0, 0.3, (len(b.mo), 2))
    if approach:
        vo[:, 0] -= 1.0  # the other set moving left, into MPM
    b.vo_f.from_numpy(vo.astype(np.float32))
    return b.gc, b.mpm, b.gm, gv, vo, b.mo, b.vo_f


def _build(ti):
    from simcli.coupling.grid_contact import GridContact, ParticleSet

    dim, f, dx = 2, ti.f32, 0.1
    shape = (16, 16)
    # two blocks on lattices of spacing dx / 2 that touch at x = 0.8: MPM left, the other set right

    def lattice(x0, x1):
        g = np.meshgrid(np.arange(x0, x1, 0.05) + 0.025, np.arange(0.4, 1.2, 0.05) + 0.025, indexing="ij")
        return np.column_stack([g[0].ravel(), g[1].ravel()])

    xm, xo = lattice(0.4, 0.8), lattice(0.8, 1.1)
    n_m, n_o = len(xm), len(xo)
    mpm = SimpleNamespace(
        dim=dim,
        f=f,
        grid_shape=shape,
        precision="f32",
        dx=dx,
        inv_dx=1.0 / dx,
        origin=np.zeros(2),
        lo_node=(2, 2),
        hi_node=(13, 13),
        flip=None,
        n=n_m,
    )
    mpm.grid_v = ti.Vector.field(dim, f, shape=shape)
    mpm.grid_m = ti.field(f, shape=shape)
    mpm.bbox_all = ti.Vector.field(dim, ti.i32, shape=2)
    mpm.x = ti.Vector.field(dim, f, shape=n_m)
    mpm.F = ti.Matrix.field(dim, dim, f, shape=n_m)
    mpm.vol = ti.field(f, shape=n_m)

    @ti.func
    def count():  # MPM's particle loops' bound (the active count with emitters or sinks)
        return n_m

    mpm.count = count
    mpm.x.from_numpy(xm.astype(np.float32))
    mpm.vol.from_numpy(np.full(n_m, 0.05**2, np.float32))
    # node masses and velocities as MPM's P2G would leave them: the particles' splat (uniform mass)
    gm = np.zeros(shape)
    for p in xm:
        X = p / dx
        b = (X - 0.5).astype(int)
        fx = X - b
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
        for i in range(3):
            for j in range(3):
                gm[b[0] + i, b[1] + j] += w[i][0] * w[j][1] * (500.0 * 0.05**2)
    mpm.grid_m.from_numpy(gm.astype(np.float32))
    mpm.bbox_all.from_numpy(np.array([[1, 1], [15, 15]], np.int32))

    xo_f = ti.Vector.field(dim, f, shape=n_o)
    vo_f = ti.Vector.field(dim, f, shape=n_o)
    mo = np.full(n_o, 1000.0 * 0.05**2)
    mo_f = ti.field(f, shape=n_o)
    xo_f.from_numpy(xo.astype(np.float32))
    mo_f.from_numpy(mo.astype(np.float32))

    @ti.func
    def pos(i):
        return xo_f[i]

    @ti.func
    def mass(i):
        return mo_f[i]

    other = ParticleSet(n=n_o, pos=pos, mass=mass, vel=vo_f, vel_dim=2, rho=1000.0, shift_x=xo_f)
    gc = GridContact(mpm, other, "test")
    gc.build()
    return {"gc": gc, "mpm": mpm, "gm": gm, "mo": mo, "vo_f": vo_f, "xo_f": xo_f, "xo": xo}


@pytest.mark.parametrize("seed", [0, 1])
def test_contact_conserves_momentum_and_never_adds_energy(ti_f32, seed):
    import taichi as ti

    gc, mpm, gm, gv, vo, mo, vo_f = _setup(ti, seed)
    gc.couple(1e-3)
    gv1 = mpm.grid_v.to_numpy().astype(np.float64)
    vo1 = vo_f.to_numpy().astype(np.float64)
    p_mpm = (gm[..., None] * (gv1 - gv)).sum(axis=(0, 1))
    p_oth = (mo[:, None] * (vo1 - vo)).sum(axis=0)
    scale = (gm[..., None] * np.abs(gv)).sum() + (mo[:, None] * np.abs(vo)).sum()
    assert np.abs(p_mpm).max() > 1e-3 * scale  # the contact acted
    assert np.abs(p_mpm + p_oth).max() < 1e-5 * scale  # and conserved momentum (f32)
    ke0 = 0.5 * (gm * (gv**2).sum(-1)).sum() + 0.5 * (mo * (vo**2).sum(-1)).sum()
    ke1 = 0.5 * (gm * (gv1**2).sum(-1)).sum() + 0.5 * (mo * (vo1**2).sum(-1)).sum()
    assert ke1 <= ke0 * (1 + 1e-6)
    # the mean x velocities no longer approach: MPM slowed, the other set pushed back
    assert (gm * gv1[..., 0]).sum() < (gm * gv[..., 0]).sum()
    assert (mo * vo1[:, 0]).sum() > (mo * vo[:, 0]).sum()


def test_separating_materials_are_left_alone(ti_f32):
    import taichi as ti

    gc, mpm, gm, gv, vo, mo, vo_f = _setup(ti, 3, approach=False)
    # move them apart: MPM left, the other right, each as a whole
    gv[...] = 0.0
    gv[..., 0] = -1.0
    gv[gm == 0] = 0.0
    mpm.grid_v.from_numpy(gv.astype(np.float32))
    vo[:] = 0.0
    vo[:, 0] = 1.0
    vo_f.from_numpy(vo.astype(np.float32))
    gc.couple(1e-3)
    assert np.allclose(mpm.grid_v.to_numpy(), gv.astype(np.float32))
    assert np.allclose(vo_f.to_numpy(), vo.astype(np.float32))
