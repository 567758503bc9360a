"""Stable fluids, the kernels on small grids (Taichi, f32, CPU): projection below its tolerance with
both solvers and every boundary kind, the multigrid preconditioner's symmetry, advection (constants
kept, second order better than first), implicit viscosity at its discrete rate, jets, restart.

Each solver configuration compiles its own kernels, so the tests share a few module-wide solvers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simcli.scene.models import Scene


def make(**kw):
    from simcli.solvers.sf.solver import SFSolver

    d = {
        "sim": {"dim": 2, "gravity": [0.0, 0.0]},
        "domain": {"lower": [0, 0], "upper": [1, 1]},
        "solvers": {"sf": {"resolution": 32}},
        "entities": [{"name": "fluid", "material": {"type": "SF.Smoke"}}],
    }
    d.update(kw)
    s = SFSolver(Scene.model_validate(d), [])
    s.build()
    return s


def set_velocity(s, v):
    s.vel.from_numpy(np.asarray(v, dtype=np.float32))
    s._init_boundary()  # walls, colliders, ghosts
    s._version += 1


def random_velocity(s, rng):
    set_velocity(s, rng.normal(size=s.vel.shape))


def set_scalars(s, density, temperature):
    sc = s.scalars.to_numpy()
    sc[(0,) + (slice(1, -1),) * s.dim] = density
    sc[(1,) + (slice(1, -1),) * s.dim] = temperature
    s.scalars.from_numpy(sc)
    s._init_boundary()
    s._version += 1


# lid, open face, slip walls, a collider and a buoyant jet: every boundary kind and source in 2D
@pytest.fixture(scope="module")
def busy(ti_f32):
    return make(
        domain={
            "lower": [0, 0],
            "upper": [1.5, 1],
            "boundary": {"type": "slip"},
            "faces": {"y+": {"type": "sticky", "velocity": [1.0, 0.0]}, "x+": {"type": "open"}},
        },
        colliders=[{"type": "Sphere", "center": [0.6, 0.45], "radius": 0.2}],
        sim={"dim": 2, "gravity": [0.0, -9.81]},
        solvers={"sf": {"resolution": 48, "tolerance": 1e-6}},
        entities=[
            {
                "name": "fluid",
                "material": {"type": "SF.Smoke", "buoyancy": -0.5},
                "jets": [
                    {
                        "position": [0.25, 0.3],
                        "radius": 0.1,
                        "density_rate": 2.0,
                        "temperature_rate": 50.0,
                        "velocity": [0.0, 0.5],
                    }
                ],
            }
        ],
    )


@pytest.fixture(scope="module")
def periodic_sl(ti_f32):
    """Periodic, semi-Lagrangian, viscous."""
    return make(
        domain={"lower": [0, 0], "upper": [1, 1], "boundary": {"type": "periodic"}},
        solvers={"sf": {"resolution": 32, "advection": "semi_lagrangian", "viscosity_tolerance": 1e-7}},
        entities=[{"name": "fluid", "material": {"type": "SF.Smoke", "viscosity": 0.01}}],
    )


def check_projected(s, dt, tol):
    its, res, rel = s.projection.solve(dt)
    s._version += 1
    div = np.abs(s.divergence()).max() * dt  # float64, on the host, from the face velocities
    assert res <= tol and div <= 1.05 * tol + 1e-7, (its, res, div)
    return its, rel


def test_projection_divergence_below_tolerance_mgpcg(busy):
    rng = np.random.default_rng(1)
    random_velocity(busy, rng)
    assert np.abs(busy.divergence()).max() * 0.01 > 1e-2
    its, rel = check_projected(busy, 0.01, 1e-6)
    assert its <= 25 and rel < 1e-3
    # fixed faces kept their values: the walls' normal velocity and the collider faces are zero
    u, v = busy._faces(0), busy._faces(1)
    assert np.allclose(v[:, -1], 0) and np.allclose(v[:, 0], 0) and np.allclose(u[0], 0)
    solid = busy.layout.flags[1:-1, 1:-1] == 1
    assert np.allclose(u[:-1][solid], 0) and np.allclose(u[1:][solid], 0)
    assert not np.allclose(u[-1], 0)  # the open face lets fluid through


def test_projection_divergence_below_tolerance_jacobi(ti_f32):
    s = make(
        domain={
            "lower": [0, 0],
            "upper": [1, 1],
            "boundary": {"type": "slip"},
            "faces": {"y+": {"type": "open"}},
        },
        solvers={
            "sf": {"resolution": 16, "pressure_solver": "jacobi", "tolerance": 1e-4, "max_iterations": 20000}
        },
    )
    random_velocity(s, np.random.default_rng(5))
    its, _ = check_projected(s, 0.01, 1e-4)
    assert its % 10 == 0  # tested every check_every sweeps


def test_projection_3d_periodic_open_collider(ti_f32):
    s = make(
        sim={"dim": 3, "gravity": [0, 0, 0]},
        domain={
            "lower": [0, 0, 0],
            "upper": [1, 1, 1],
            "boundary": {"type": "slip"},
            "faces": {"x-": {"type": "periodic"}, "x+": {"type": "periodic"}, "z+": {"type": "open"}},
        },
        colliders=[{"type": "Box", "lower": [0.3, 0.3, 0.3], "upper": [0.6, 0.5, 0.7]}],
        solvers={"sf": {"resolution": 16, "tolerance": 1e-6}},
    )
    random_velocity(s, np.random.default_rng(2))
    its, _ = check_projected(s, 0.01, 1e-6)
    assert its <= 30
    u = s._faces(0)
    assert np.allclose(u[0], u[-1])  # periodic: face n is face 0


def test_multigrid_preconditioner_is_symmetric_and_positive(busy):
    P = busy.projection
    D = P.D[0].to_numpy()
    fluid = D > 0
    rng = np.random.default_rng(3)

    def V(r):
        P.r.from_numpy(np.where(fluid, r, 0).astype(np.float32))
        P.precondition()
        return P.z.to_numpy().astype(np.float64)

    r1, r2 = rng.normal(size=D.shape), rng.normal(size=D.shape)
    r1[~fluid] = r2[~fluid] = 0
    a, b = (V(r1) * r2).sum(), (r1 * V(r2)).sum()
    assert abs(a - b) <= 1e-4 * abs(a)  # symmetric, so CG may use it
    assert (V(r1) * r1).sum() > 0 and (V(r2) * r2).sum() > 0


def _sine(s):
    x = s.layout.cell_centres()
    return np.sin(2 * math.pi * x[0]) * np.cos(2 * math.pi * x[1])


def _translate(s):
    """Uniform velocity (1, 1) m/s across the periodic unit square for 1 s (back where it started) at
    a CFL number of 1.6: returns the largest error of the advected sine; constants must stay exact."""
    v = np.zeros(s.vel.shape)
    v[...] = 1.0
    set_velocity(s, v)
    q0 = _sine(s)
    set_scalars(s, q0, 300.0)
    for _ in range(20):
        s.advector.advect(0.05)
    s._version += 1
    assert np.abs(s._full("temperature") - 300.0).max() < 1e-3
    assert np.allclose(s.cell_velocity(), 1.0, atol=1e-5)
    return np.abs(s._full("density") - q0).max()


def test_advection_maccormack_beats_semi_lagrangian(periodic_sl):
    err_sl = _translate(periodic_sl)
    mc = make(
        domain={"lower": [0, 0], "upper": [1, 1], "boundary": {"type": "periodic"}},
        solvers={"sf": {"resolution": 32, "advection": "maccormack"}},
    )
    err_mc = _translate(mc)
    assert err_sl < 0.25 and err_mc < 0.08 and err_mc < 0.5 * err_sl, (err_sl, err_mc)


def test_viscosity_decays_a_shear_mode_at_the_discrete_rate(periodic_sl):
    """u = sin(2 pi y), v = 0 in a periodic box: advection leaves it alone, backward Euler multiplies
    it by 1 / (1 + nu dt lambda) per step, lambda = (2 - 2 cos(k h)) / h^2 the discrete eigenvalue."""
    s = periodic_sl
    nu, dt, n = 0.01, 0.05, 32
    v = np.zeros(s.vel.shape)
    y = (np.arange(-1, n + 2) + 0.5) / n
    v[0] = np.sin(2 * math.pi * y)[None, :]
    set_velocity(s, v)
    a0 = np.abs(s._faces(0)).max()
    steps = 20
    for _ in range(steps):
        s.substep(dt)
    s._version += 1
    h = 1.0 / n
    lam = (2 - 2 * math.cos(2 * math.pi * h)) / h**2
    expect = (1 + nu * dt * lam) ** -steps
    ratio = np.abs(s._faces(0)).max() / a0
    assert abs(ratio / expect - 1) < 1e-3, (ratio, expect)
    assert np.abs(s._faces(1)).max() < 1e-5


def test_jet_adds_smoke_at_its_rate_and_restart_is_bitwise(busy):
    rate, R, dt = 2.0, 0.1, 0.01
    set_velocity(busy, np.zeros(busy.vel.shape))
    set_scalars(busy, 0.0, 293.15)
    busy.substep(dt)
    busy._version += 1
    added = busy._full("density").sum() * busy.layout.dx[0] * busy.layout.dx[1]
    assert abs(added / (rate * dt * math.pi * R**2) - 1) < 0.03
    assert abs(busy._full("temperature").max() - (293.15 + 50 * dt)) < 1e-3
    for _ in range(4):
        busy.substep(dt)
    st = busy.get_state()
    for _ in range(3):
        busy.substep(dt)
    a = busy.get_state()
    busy.set_state(st)
    for _ in range(3):
        busy.substep(dt)
    b = busy.get_state()
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    # the light smoke rises: the smoke-weighted vertical velocity is upwards
    busy._version += 1
    assert (busy.cell_velocity()[..., 1] * busy._full("density")).sum() > 0
