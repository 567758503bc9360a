"""Maths of the MPM solver's single functions: rotation extraction vs an SVD polar
decomposition, constitutive laws (zero at rest, frame indifference, derivative of the energy),
and the P2G / G2P transfers (mass and momentum conservation)."""

import numpy as np
import pytest


def svd_polar_rotation(F):
    """Rotation maximising tr(R^T F) over SO(n): U diag(1, .., det(U V^T)) V^T."""
    U, _, Vt = np.linalg.svd(F)
    D = np.eye(F.shape[0])
    D[-1, -1] = np.sign(np.linalg.det(U @ Vt))
    return U @ D @ Vt


def random_rotation(rng, n=3):
    Q, R = np.linalg.qr(rng.normal(size=(n, n)))
    Q = Q @ np.diag(np.sign(np.diag(R)))
    if np.linalg.det(Q) < 0:
        Q[:, 0] *= -1
    return Q


def random_F(rng, n=3, lo=0.6, hi=1.6, invert=False):
    s = rng.uniform(lo, hi, size=n)
    if invert:
        s[-1] *= -1
    return random_rotation(rng, n) @ np.diag(s) @ random_rotation(rng, n)


@pytest.fixture(scope="module")
def rot_kernels(ti_f32):
    import taichi as ti

    from simcli.solvers.mpm.constitutive import extract_rotation, polar_rotation_2d, quat_to_mat

    n = 64
    F3 = ti.Matrix.field(3, 3, ti.f32, shape=n)
    R3 = ti.Matrix.field(3, 3, ti.f32, shape=n)
    q = ti.Vector.field(4, ti.f32, shape=n)
    F2 = ti.Matrix.field(2, 2, ti.f32, shape=n)
    R2 = ti.Matrix.field(2, 2, ti.f32, shape=n)

    @ti.kernel
    def rot3(iters: ti.i32):
        for p in range(n):
            # the iteration count is a template in the solver; here a loop of single steps
            qq = q[p]
            for _ in range(iters):
                qq = extract_rotation(F3[p], qq, 1, 1e-12)
            q[p] = qq
            R3[p] = quat_to_mat(qq)

    @ti.kernel
    def rot2():
        for p in range(n):
            R2[p] = polar_rotation_2d(F2[p])

    return {"n": n, "F3": F3, "R3": R3, "q": q, "F2": F2, "R2": R2, "rot3": rot3, "rot2": rot2}


def _cold_start(k, Fs, iters):
    n = k["n"]
    k["F3"].from_numpy(Fs.astype(np.float32))
    q0 = np.zeros((n, 4), np.float32)
    q0[:, 0] = 1
    k["q"].from_numpy(q0)
    k["rot3"](iters)
    return k["R3"].to_numpy()


def test_rotation_extraction_matches_svd_polar(rot_kernels):
    rng = np.random.default_rng(1)
    Fs = np.stack([random_F(rng) for _ in range(rot_kernels["n"])])
    R = _cold_start(rot_kernels, Fs, 60)  # from the identity: large rotations need a few dozen iterations
    for i in range(len(Fs)):
        ref = svd_polar_rotation(Fs[i])
        assert np.allclose(R[i], ref, atol=2e-4), (i, R[i], ref)
        assert np.allclose(R[i] @ R[i].T, np.eye(3), atol=1e-5)


def test_rotation_extraction_of_inverted_F_maximises_the_same_objective(rot_kernels):
    """det F < 0: the rotation-variant SVD polar R = U diag(1, 1, -1) V^T maximises tr(R^T F)
    over SO(3); the iteration approaches the same maximum (slowly, from a cold start)."""
    rng = np.random.default_rng(11)
    Fs = np.stack([random_F(rng, invert=True) for _ in range(rot_kernels["n"])])
    R = _cold_start(rot_kernels, Fs, 400)
    for i in range(len(Fs)):
        best = np.trace(svd_polar_rotation(Fs[i]).T @ Fs[i])
        assert np.trace(R[i].T @ Fs[i]) == pytest.approx(best, rel=1e-3, abs=1e-3)
        assert np.linalg.det(R[i]) == pytest.approx(1.0, abs=1e-4)


def test_rotation_extraction_warm_start_tracks_a_deformation_path(rot_kernels):
    """The solver's use: at most ``rotation_iters`` iterations per substep, from the previous
    substep's rotation. Path: a rotation of 0.02 rad per substep (50 rad/s at dt = 4e-4 s) times a
    symmetric stretch growing to 0.7 - 1.4 over 40 substeps."""
    import taichi as ti

    from simcli.solvers.mpm.constitutive import CorotatedLaw

    iters = CorotatedLaw(3, ti.f32).rotation_iters
    k = rot_kernels
    rng = np.random.default_rng(2)
    n = k["n"]
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    stretch = []  # symmetric positive definite: the polar rotation of Rot @ S is Rot
    for _ in range(n):
        Q = random_rotation(rng)
        stretch.append(Q @ np.diag(rng.uniform(0.7, 1.4, 3)) @ Q.T)
    q0 = np.zeros((n, 4), np.float32)
    q0[:, 0] = 1
    k["q"].from_numpy(q0)
    worst = 0.0
    for step in range(1, 41):
        theta = 0.02 * step
        Fs = []
        for i in range(n):
            a = axes[i]
            K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            Rot = np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K
            Fs.append(Rot @ (np.eye(3) + (stretch[i] - np.eye(3)) * step / 40))
        Fs = np.stack(Fs)
        k["F3"].from_numpy(Fs.astype(np.float32))
        k["rot3"](iters)
        R = k["R3"].to_numpy()
        for i in range(n):
            worst = max(worst, float(np.abs(R[i] - svd_polar_rotation(Fs[i])).max()))
    assert worst < 1e-4


def test_polar_rotation_2d(rot_kernels):
    k = rot_kernels
    rng = np.random.default_rng(3)
    n = k["n"]
    Fs = np.stack([random_F(rng, n=2, invert=(i % 8 == 7)) for i in range(n)])
    k["F2"].from_numpy(Fs.astype(np.float32))
    k["rot2"]()
    R = k["R2"].to_numpy()
    for i in range(n):
        assert np.allclose(R[i], svd_polar_rotation(Fs[i]), atol=1e-5)


# ------------------------------------------------------------------ constitutive laws


def energy(model, F, mu, lam):
    J = np.linalg.det(F)
    if model == "corotation":
        R = svd_polar_rotation(F)
        return mu * np.sum((F - R) ** 2) + 0.5 * lam * (J - 1) ** 2
    d = F.shape[0]
    return 0.5 * mu * (np.trace(F.T @ F) - d) - mu * np.log(J) + 0.5 * lam * np.log(J) ** 2


@pytest.fixture(scope="module")
def law_kernels(ti_f32):
    import taichi as ti

    from simcli.solvers.mpm.laws import LAWS

    n = 16
    out = {}
    for dim in (2, 3):
        for key, cls in LAWS.items():
            law = cls(dim, ti.f32)
            law.allocate(n)
            law.init_state()
            Fin = ti.Matrix.field(dim, dim, ti.f32, shape=n)
            tau = ti.Matrix.field(dim, dim, ti.f32, shape=n)

            @ti.kernel
            def run(mu: ti.f32, lam: ti.f32, law: ti.template(), Fin: ti.template(), tau: ti.template()):
                for p in range(n):
                    F = Fin[p]
                    tau[p] = law.kirchhoff(p, F, F.determinant(), mu, lam, False)

            out[(dim, key)] = (law, Fin, tau, run)
    return n, out


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("model", ["corotation", "neohooken"])
def test_stress_zero_at_rest_and_under_rotation(law_kernels, dim, model):
    n, kernels = law_kernels
    law, Fin, tau, run = kernels[(dim, model)]
    rng = np.random.default_rng(4)
    Fs = np.stack([np.eye(dim)] + [random_rotation(rng, dim) for _ in range(n - 1)])
    Fin.from_numpy(Fs.astype(np.float32))
    run(1.0e5, 2.0e5, law, Fin, tau)
    assert np.abs(tau.to_numpy()[0]).max() == 0.0  # exactly zero at F = I
    assert np.abs(tau.to_numpy()).max() < 1e-5 * 2.0e5  # pure rotations: no stress


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("model", ["corotation", "neohooken"])
def test_kirchhoff_stress_is_the_energy_derivative(law_kernels, dim, model):
    """tau = (d psi / d F) F^T, with psi the law's energy density, by central differences."""
    n, kernels = law_kernels
    law, Fin, tau, run = kernels[(dim, model)]
    rng = np.random.default_rng(5)
    Fs = np.stack([random_F(rng, n=dim, lo=0.7, hi=1.4) for _ in range(n)])
    Fin.from_numpy(Fs.astype(np.float32))
    mu, lam = 1.0e5, 2.0e5
    run(mu, lam, law, Fin, tau)
    got = tau.to_numpy()
    h = 1e-6
    for p in range(n):
        P = np.zeros((dim, dim))
        for a in range(dim):
            for b in range(dim):
                E = np.zeros((dim, dim))
                E[a, b] = h
                P[a, b] = (energy(model, Fs[p] + E, mu, lam) - energy(model, Fs[p] - E, mu, lam)) / (2 * h)
        ref = P @ Fs[p].T
        assert np.allclose(got[p], ref, rtol=1e-3, atol=2e-4 * np.abs(ref).max()), (p, got[p], ref)


# ------------------------------------------------------------------- transfers


def _lattice(lo, hi, h):
    axes = [np.arange(a + h / 2, b - h / 4, h) for a, b in zip(lo, hi)]
    g = np.meshgrid(*axes, indexing="ij")
    return np.stack([c.ravel() for c in g], axis=1)


@pytest.fixture(scope="module")
def transfer_solver(ti_f32):
    from simcli.scene.models import Scene
    from simcli.solvers.base import Body
    from simcli.solvers.mpm.solver import MPMSolver

    scene = Scene.model_validate(
        {
            "sim": {"dim": 3, "gravity": [0.0, 0.0, 0.0]},
            "domain": {"lower": [0, 0, 0], "upper": [0.5, 0.5, 0.5]},
            "solvers": {"mpm": {"grid_density": 32}},
            "entities": [
                {
                    "name": "b",
                    "material": {"type": "MPM.Elastic", "E": 1e5, "nu": 0.3, "rho": 800},
                    "morph": {"type": "Box", "lower": [0.15, 0.15, 0.15], "upper": [0.35, 0.35, 0.35]},
                }
            ],
        }
    )
    x = _lattice([0.15] * 3, [0.35] * 3, 0.02)
    rng = np.random.default_rng(6)
    x = x + rng.uniform(-0.004, 0.004, size=x.shape)  # off the lattice: all weights in play
    n = len(x)
    body = Body(
        "b",
        scene.entities[0],
        x,
        np.zeros_like(x),
        np.full(n, 0.008 / n),
        rng.uniform(0.5, 1.5, n) * 6.4 / n,
        np.zeros(n, bool),
    )
    solver = MPMSolver(scene, [body])
    solver.build()
    return solver, body


def _grid_totals(solver):
    """Mass and momentum on the grid after p2g, summed over the private copies' valid boxes."""
    g = solver.grid.to_numpy()
    bb = solver.bbox.to_numpy()
    mass = 0.0
    mom = np.zeros(solver.dim)
    for t in range(solver.T):
        lo, hi = bb[t, 0], bb[t, 1]
        sub = g[t, lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]].astype(np.float64)
        mass += sub[..., solver.dim].sum()
        mom += sub[..., : solver.dim].reshape(-1, solver.dim).sum(axis=0)
    return mass, mom


def test_p2g_g2p_conserve_mass_and_momentum(transfer_solver):
    solver, body = transfer_solver
    rng = np.random.default_rng(7)
    n, dim = body.n, 3
    state = solver.get_state()
    state["v"] = rng.normal(scale=0.5, size=(n, dim)).astype(np.float32)
    state["C"] = rng.normal(scale=2.0, size=(n, dim, dim)).astype(np.float32)
    state["F"] = (np.eye(dim) + rng.normal(scale=0.05, size=(n, dim, dim))).astype(np.float32)  # stressed
    solver.set_state(state)
    m = solver.mass.to_numpy().astype(np.float64)
    p_before = (m[:, None] * state["v"]).sum(axis=0)

    dt = 1e-4
    solver.kernels.stage_p2g(dt)
    gm, gp = _grid_totals(solver)
    assert gm == pytest.approx(m.sum(), rel=1e-5)
    # affine (m C) and stress terms cancel in the sum: sum_i w_i (x_i - x_p) = 0
    assert np.allclose(gp, p_before, rtol=1e-4, atol=1e-5 * np.abs(m[:, None] * state["v"]).sum())

    solver.kernels.stage_grid_update(dt)  # no gravity, body far from the walls: node momentum unchanged
    solver.kernels.stage_g2p(dt)
    v_after = solver.v.to_numpy().astype(np.float64)
    p_after = (m[:, None] * v_after).sum(axis=0)
    # APIC: sum_p m_p sum_i w_ip v_i = sum_i m_i v_i
    assert np.allclose(p_after, gp, rtol=1e-4, atol=1e-5 * np.abs(m[:, None] * state["v"]).sum())


def test_uniform_velocity_is_transferred_exactly(transfer_solver):
    solver, body = transfer_solver
    n, dim = body.n, 3
    state = solver.get_state()
    u = np.array([0.3, -0.2, 0.1], np.float32)
    state["v"] = np.broadcast_to(u, (n, dim)).copy()
    state["C"] = np.zeros((n, dim, dim), np.float32)
    state["F"] = np.broadcast_to(np.eye(dim, dtype=np.float32), (n, dim, dim)).copy()
    solver.set_state(state)
    dt = 1e-4
    solver.kernels.stage_p2g(dt)
    solver.kernels.stage_grid_update(dt)
    solver.kernels.stage_g2p(dt)
    assert np.allclose(solver.v.to_numpy(), u, atol=1e-6)
    assert np.abs(solver.C.to_numpy()).max() < 1e-3  # partition of unity: no spurious gradient


@pytest.fixture(scope="module")
def svd_kernels(ti_f32):
    import taichi as ti

    from simcli.solvers.mpm.constitutive import mat_to_quat, quat_to_mat
    from simcli.solvers.mpm.plasticity import svd3_via_b, svd3_via_b_warm

    n = 64
    F = ti.Matrix.field(3, 3, ti.f32, shape=n)
    U0 = ti.Matrix.field(3, 3, ti.f32, shape=n)
    out = {k: ti.Matrix.field(3, 3, ti.f32, shape=n) for k in ("Uc", "Vc", "Uw", "Vw", "Rq")}
    s = {k: ti.Vector.field(3, ti.f32, shape=n) for k in ("sc", "sw")}

    @ti.kernel
    def run():
        for p in range(n):
            Uc, sc, Vc = svd3_via_b(F[p])
            Uw, sw, Vw = svd3_via_b_warm(F[p], U0[p])
            out["Uc"][p], out["Vc"][p], s["sc"][p] = Uc, Vc, sc
            out["Uw"][p], out["Vw"][p], s["sw"][p] = Uw, Vw, sw
            out["Rq"][p] = quat_to_mat(mat_to_quat(U0[p]))

    return {"n": n, "F": F, "U0": U0, "run": run, **out, **s}


@pytest.mark.parametrize("guess", ["identity", "random", "near"])
def test_warm_started_svd_is_the_svd_from_any_start(svd_kernels, guess):
    """svd3_via_b_warm (the plastic laws' decomposition, warm-started from the particle's last U) gives
    F = U diag(s) V^T with U, V rotations and the same singular values as the cold start, whatever the
    guess: identity, an unrelated rotation, or the true U turned by a few degrees (the case it is for).
    mat_to_quat inverts quat_to_mat on rotations."""
    k = svd_kernels
    n = k["n"]
    rng = np.random.default_rng(7)
    Fs = np.stack([random_F(rng, invert=(i % 8 == 0)) for i in range(n)])
    if guess == "identity":
        U0 = np.stack([np.eye(3)] * n)
    elif guess == "random":
        U0 = np.stack([random_rotation(rng) for _ in range(n)])
    else:
        U0 = []
        for F in Fs:
            U = np.linalg.svd(F)[0]
            U = U if np.linalg.det(U) > 0 else U @ np.diag([1, 1, -1])
            a = rng.normal(size=3)
            a *= np.radians(5) / np.linalg.norm(a)
            K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            th = np.linalg.norm(a)
            U0.append(U @ (np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * K @ K))
        U0 = np.stack(U0)
    k["F"].from_numpy(Fs.astype(np.float32))
    k["U0"].from_numpy(U0.astype(np.float32))
    k["run"]()
    Uw, Vw, sw = k["Uw"].to_numpy(), k["Vw"].to_numpy(), k["sw"].to_numpy()
    sc = k["sc"].to_numpy()
    for i in range(n):
        np.testing.assert_allclose(Uw[i] @ np.diag(sw[i]) @ Vw[i].T, Fs[i], atol=2e-5)
        np.testing.assert_allclose(Uw[i].T @ Uw[i], np.eye(3), atol=2e-6)
        np.testing.assert_allclose(Vw[i].T @ Vw[i], np.eye(3), atol=2e-5)
        assert np.linalg.det(Uw[i]) > 0 and np.linalg.det(Vw[i]) > 0
        # singular values as a set (the order of the columns depends on the start), signs included
        np.testing.assert_allclose(np.sort(sw[i]), np.sort(sc[i]), rtol=2e-5, atol=2e-6)
        np.testing.assert_allclose(np.sort(np.abs(sw[i])), np.linalg.svd(Fs[i])[1][::-1], rtol=2e-5)
    np.testing.assert_allclose(k["Rq"].to_numpy(), U0, atol=2e-6)
