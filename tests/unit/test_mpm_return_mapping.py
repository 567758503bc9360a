"""Single-particle return mappings of the MPM plastic laws, against exact answers.

Each law's ``return_mapping`` and ``kirchhoff`` run on a batch of independent particles in a
small kernel (f32, the solver's default), so "exact" means to f32 round-off:

* von Mises (Hencky + radial return): uniaxial stress saturates at the yield stress, pure shear
  at yield / sqrt(3), the elastic range is Hencky's tau = E ln(stretch), and the von Mises
  Cauchy stress never exceeds the yield stress for any trial F; 2D is plane strain;
* clamp and snow: the singular values end in [1 - theta_c, 1 + theta_s], J_p J_E = J along a
  random deformation path, snow's stress is the corotated one scaled by exp(xi (1 - J_p));
* sand (Drucker-Prager): the stress ends on or inside the cone, separation is stress-free and
  its volume is remembered and given back, the return keeps the volume (no dilatancy), J_p J_E = J;
* liquid: F becomes J^(1/d) I; muscle: the active stress k a (F f0)(F f0)^T.
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest

SY = 1.0e4  # yield stress [Pa]
E, NU = 1.0e6, 0.3
MU = E / (2 * (1 + NU))
LAM = E * NU / ((1 + NU) * (1 - 2 * NU))


def random_rotation(rng, n=3):
    Q, R = np.linalg.qr(rng.normal(size=(n, n)))
    Q = Q @ np.diag(np.sign(np.diag(R)))
    if np.linalg.det(Q) < 0:
        Q[:, 0] *= -1
    return Q


def mat(**kw):
    from simcli.scene.models import Scene

    kw.setdefault("E", E)
    kw.setdefault("nu", NU)
    s = Scene.model_validate(
        {
            "entities": [
                {
                    "name": "a",
                    "material": kw,
                    "morph": {"type": "Sphere", "center": [0, 0, 0.5], "radius": 0.1},
                }
            ]
        }
    )
    return s.entities[0].material


class Harness:
    """One law, n independent particles: F_E in, return mapping, F_E and tau out."""

    def __init__(self, material, dim=3, n=64):
        import taichi as ti

        from simcli.solvers.mpm.constitutive import elastic_moduli, law_key
        from simcli.solvers.mpm.laws import LAWS

        self.ti = ti
        self.n, self.dim = n, dim
        self.mu, self.lam = elastic_moduli(material)
        law = LAWS[law_key(material)](dim, ti.f32)
        law.allocate(n)
        law.allocate_materials([material])
        self.C = ti.Matrix.field(dim, dim, ti.f32, shape=n)
        body = SimpleNamespace(name="a", n=n, x=np.zeros((n, dim)))  # muscle groups are assigned per body
        fake = SimpleNamespace(
            mid=ti.field(ti.i32, shape=n),
            C=self.C,
            n=n,
            bodies=[body],
            body_mid=[0],
            offsets=np.array([0, n]),
            materials=[material],
        )
        law.bind(fake)
        law.init_state()
        self.law = law
        self.Fin = ti.Matrix.field(dim, dim, ti.f32, shape=n)
        self.Fout = ti.Matrix.field(dim, dim, ti.f32, shape=n)
        self.tau = ti.Matrix.field(dim, dim, ti.f32, shape=n)
        self.tzz = ti.field(ti.f32, shape=n)
        self.Je = ti.field(ti.f32, shape=n)
        self.jp = ti.field(ti.f32, shape=n)
        Fin, Fout, tau, tzz, Je, jp = self.Fin, self.Fout, self.tau, self.tzz, self.Je, self.jp

        @ti.kernel
        def step(mu: ti.f32, lam: ti.f32, plastic: ti.i32):
            for p in range(n):
                F = Fin[p]
                if plastic:
                    F = law.return_mapping(p, F, 0, mu, lam)
                J = F.determinant()
                Fout[p] = F
                tau[p] = law.kirchhoff(p, F, J, mu, lam, True)
                tzz[p] = law.tau_zz(p, F, J, mu, lam)
                Je[p] = law.elastic_J(p, J)
                jp[p] = law.plastic_J(p)

        self._step = step

    def run(self, F, plastic=True):
        F = np.ascontiguousarray(np.broadcast_to(F, (self.n, self.dim, self.dim)), dtype=np.float32)
        self.Fin.from_numpy(F)
        self._step(self.mu, self.lam, int(plastic))
        return self.Fout.to_numpy().astype(np.float64), self.tau.to_numpy().astype(np.float64)

    def state(self):
        return self.law.get_state()

    def set_state(self, st):
        self.law.set_state(st)


def cauchy3(tau, tzz, Je):
    """3x3 Cauchy stresses from (2D or 3D) Kirchhoff stresses (2D: plane strain, tau_zz)."""
    n, d = tau.shape[:2]
    s = np.zeros((n, 3, 3))
    s[:, :d, :d] = tau
    if d == 2:
        s[:, 2, 2] = tzz
    return s / Je[:, None, None]


def von_mises(s):
    dev = s - np.eye(3) * (np.trace(s, axis1=1, axis2=2) / 3)[:, None, None]
    return np.sqrt(1.5 * (dev**2).sum(axis=(1, 2)))


# ----------------------------------------------------------------------------- von Mises


@pytest.fixture(scope="module")
def vm3(ti_f32):
    return Harness(mat(type="MPM.ElastoPlastic", von_mises_yield_stress=SY), dim=3, n=48)


def uniaxial(h: Harness, stretch: np.ndarray, axis_rot=None):
    """Uniaxial stress: for each axial stretch, the lateral stretch with zero lateral stress
    (bisection on all particles at once). Returns (tau, F_out, tzz, Je)."""
    d = h.dim
    R = np.eye(d) if axis_rot is None else axis_rot
    start = {k: v.copy() for k, v in h.state().items()}  # every trial starts from the same state

    def lateral_stress(lat):
        h.set_state(start)
        F = np.zeros((h.n, d, d))
        F[:, 0, 0] = stretch
        for i in range(1, d):
            F[:, i, i] = lat
        F = R @ F @ R.T
        _, tau = h.run(F)
        return (R.T @ tau @ R)[:, 1, 1]

    # bisection (robust to f32 noise): the lateral stress rises with the lateral stretch; a
    # stretched bar contracts sideways (at most to 1 / stretch), so the root lies in [0.5, 1]
    lo_, hi_ = np.full(h.n, 0.5), np.full(h.n, 1.0)
    for _ in range(25):  # 0.5 / 2^25: below f32 resolution
        mid = 0.5 * (lo_ + hi_)
        pos = lateral_stress(mid) > 0
        hi_ = np.where(pos, mid, hi_)
        lo_ = np.where(pos, lo_, mid)
    lat_b = 0.5 * (lo_ + hi_)
    F = np.zeros((h.n, d, d))
    F[:, 0, 0] = stretch
    for i in range(1, d):
        F[:, i, i] = lat_b
    h.set_state(start)
    Fo, tau = h.run(R @ F @ R.T)
    return R.T @ tau @ R, Fo, h.tzz.to_numpy().astype(np.float64), h.Je.to_numpy().astype(np.float64)


def test_von_mises_uniaxial_stress_saturates_at_the_yield_stress(vm3):
    h = vm3
    eps_y = SY / E  # Hencky uniaxial: tau_11 = E ln(stretch) until yield
    logs = np.linspace(0.05 * eps_y, 40 * eps_y, h.n)
    tau, _, _, Je = uniaxial(h, np.exp(logs), random_rotation(np.random.default_rng(1)))
    sigma11 = tau[:, 0, 0] / Je
    elastic = logs < 0.99 * eps_y
    assert np.abs(tau[:, 1, 1]).max() < 1e-3 * SY and np.abs(tau[:, 2, 2]).max() < 1e-3 * SY
    # Hencky: exact in ln(stretch), to f32 round-off (ln of a stretch 1 + 5e-4 carries ~2e-4 relative error)
    assert np.allclose(tau[elastic, 0, 0], E * logs[elastic], rtol=1e-4, atol=1e-4 * SY)
    plastic = logs > 1.01 * eps_y
    assert plastic.sum() > 30
    assert np.allclose(sigma11[plastic], SY, rtol=1e-4)  # saturates at the yield stress (Cauchy)


def test_von_mises_pure_shear_saturates_at_yield_over_sqrt3(vm3):
    h = vm3
    rng = np.random.default_rng(2)
    gam = np.linspace(0.02, 3.0, h.n) * SY / (2 * MU)
    F = np.zeros((h.n, 3, 3))
    F[:, 0, 0], F[:, 1, 1], F[:, 2, 2] = np.exp(gam), np.exp(-gam), 1.0
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    R45 = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])  # principal axes at 45 deg: a shear in x-y
    Q = random_rotation(rng)
    _, tau = h.run(Q @ R45 @ F @ R45.T @ Q.T)
    t = Q.T @ tau @ Q  # back to the shear frame
    shear = np.abs(t[:, 0, 1])
    yield_at = SY / math.sqrt(3)
    elastic = 2 * MU * gam < 0.99 * yield_at
    assert np.allclose(
        shear[elastic], 2 * MU * gam[elastic], rtol=1e-4, atol=1e-4 * SY
    )  # 2 mu gamma (Hencky)
    assert np.allclose(shear[~elastic & (2 * MU * gam > 1.01 * yield_at)], yield_at, rtol=1e-4)
    assert np.abs(t[:, 0, 0]).max() < 1e-4 * SY and np.abs(t[:, 2, 2]).max() < 1e-4 * SY


def test_von_mises_never_exceeds_the_yield_surface_and_keeps_volume(vm3):
    h = vm3
    rng = np.random.default_rng(3)
    F = np.stack(
        [random_rotation(rng) @ np.diag(rng.uniform(0.9, 1.1, 3)) @ random_rotation(rng) for _ in range(h.n)]
    )
    Fo, tau = h.run(F)
    Je = h.Je.to_numpy().astype(np.float64)
    vm = von_mises(tau / Je[:, None, None])
    assert vm.max() <= SY * (1 + 1e-4)
    yielded = vm > 0.999 * SY
    assert yielded.sum() > h.n // 2  # these trial strains are far beyond yield: most project
    # plastic flow is isochoric: det F_E unchanged by the return
    assert np.allclose(np.linalg.det(Fo), np.linalg.det(F), rtol=1e-5)
    # the projection keeps the principal directions: tau commutes with F F^T
    b = Fo @ Fo.transpose(0, 2, 1)
    comm = tau @ b - b @ tau
    assert np.abs(comm).max() < 1e-4 * SY
    # a second return mapping of a projected state changes nothing (consistency)
    Fo2, tau2 = h.run(Fo)
    assert np.allclose(Fo2, Fo, atol=2e-6) and np.allclose(tau2, tau, atol=1e-3 * SY)


def test_von_mises_2d_is_plane_strain(ti_f32):
    """2D: uniaxial in-plane stress with F_zz = 1; the out-of-plane stress is what plane strain
    gives, and the von Mises stress of the full 3D tensor saturates at the yield stress."""
    h = Harness(mat(type="MPM.ElastoPlastic", von_mises_yield_stress=SY), dim=2, n=32)
    logs = np.linspace(0.05, 40, h.n) * SY / E
    tau, _, tzz, Je = uniaxial(h, np.exp(logs))
    s = cauchy3(tau, tzz, Je)
    vm = von_mises(s)
    assert np.abs(tau[:, 1, 1]).max() < 1e-3 * SY
    plastic = logs > 3 * SY / E
    assert np.allclose(vm[plastic], SY, rtol=1e-4)
    # elastic plane strain: sigma_zz = nu sigma_xx
    elastic = logs < 0.5 * SY / E
    assert np.allclose(tzz[elastic], NU * tau[elastic, 0, 0], rtol=1e-3)


# --------------------------------------------------------------------- clamp and snow


@pytest.mark.parametrize("kind", ["clamp", "snow"])
@pytest.mark.parametrize("dim", [2, 3])
def test_clamp_keeps_singular_values_in_range_and_jp_je_equals_j(ti_f32, kind, dim):
    tc, ts, xi = 2.5e-2, 7.5e-3, 10.0
    m = (
        mat(type="MPM.ElastoPlastic", use_von_mises=False, yield_lower=tc, yield_higher=ts)
        if kind == "clamp"
        else mat(type="MPM.Snow", yield_lower=tc, yield_higher=ts, hardening=xi)
    )
    h = Harness(m, dim=dim, n=32)
    rng = np.random.default_rng(4)
    FE = np.broadcast_to(np.eye(dim), (h.n, dim, dim)).copy()
    J = np.ones(h.n)  # total volume ratio: product of det(I + dt C)
    jp = np.ones(h.n)
    for _ in range(30):
        dF = np.stack([np.eye(dim) + 0.03 * rng.normal(size=(dim, dim)) for _ in range(h.n)])
        J *= np.linalg.det(dF)
        trial = (dF @ FE).astype(np.float32).astype(np.float64)
        jp_old = jp
        FE, tau = h.run(trial)
        sv = np.linalg.svd(FE, compute_uv=False)
        assert sv.min() >= (1 - tc) * (1 - 1e-6) and sv.max() <= (1 + ts) * (1 + 1e-6)
        jp = h.jp.to_numpy().astype(np.float64)
        # J_p J_E = J: exact in each return (f32 round-off), and along the whole path
        assert np.allclose(jp * np.linalg.det(FE), jp_old * np.linalg.det(trial), rtol=3e-6)
        assert np.allclose(jp * np.linalg.det(FE), J, rtol=1e-4)
    # stress: fixed corotated of F_E (x exp(xi (1 - J_p)) for snow)
    jp = h.jp.to_numpy().astype(np.float64)
    hard = np.exp(xi * (1 - jp)) if kind == "snow" else np.ones(h.n)
    for p in range(h.n):
        U, _, Vt = np.linalg.svd(FE[p])
        R = U @ Vt
        Je = np.linalg.det(FE[p])
        ref = hard[p] * (2 * MU * (FE[p] - R) @ FE[p].T + LAM * Je * (Je - 1) * np.eye(dim))
        assert np.allclose(tau[p], ref, atol=2e-4 * np.abs(ref).max() + 1e-3), p
    assert (jp < 0.95).any() and (jp > 1.05).any()  # the path did both compact and stretch


# ---------------------------------------------------------------------------------- sand


def dp_yield(tau, alpha, apex=0.0):
    """Drucker-Prager f = |dev tau| + alpha (tr tau - 3 apex) (<= 0 admissible), 3x3 Kirchhoff."""
    tr = np.trace(tau, axis1=1, axis2=2)
    dev = tau - np.eye(3) * (tr / 3)[:, None, None]
    return np.sqrt((dev**2).sum(axis=(1, 2))) + alpha * (tr - 3 * apex)


@pytest.mark.parametrize("cohesion", [0.0, 2.0e3])
def test_sand_ends_on_or_inside_the_cone(ti_f32, cohesion):
    # the cone's check: drucker_prager named, so that it stays the cone's whatever the default (the
    # pyramid's equivalent is test_mohr_coulomb_sand_ends_on_or_inside_the_pyramid)
    m = mat(type="MPM.Sand", friction_angle=30.0, cohesion=cohesion, yield_surface="drucker_prager")
    h = Harness(m, dim=3, n=64)
    rng = np.random.default_rng(5)
    # compressive and tensile trial strains with large shear
    F = np.stack(
        [
            random_rotation(rng) @ np.diag(rng.uniform(0.95, 1.03, 3)) @ random_rotation(rng)
            for _ in range(h.n)
        ]
    )
    Fo, tau = h.run(F)
    apex = cohesion / math.tan(math.radians(30.0))
    f = dp_yield(tau, m.alpha, apex)
    scale = np.abs(tau).max() + 1.0
    assert f.max() <= 1e-4 * scale
    on_cone = f > -1e-4 * scale
    assert on_cone.sum() > h.n // 4
    tr = np.trace(tau, axis1=1, axis2=2) / 3
    assert tr.max() <= apex * (1 + 1e-4) + 1e-3  # mean stress never beyond the apex
    # no dilatancy: where the return lands on the cone (not the apex), det F_E is unchanged
    at_apex = np.isclose(np.linalg.svd(Fo, compute_uv=False).std(axis=1), 0.0, atol=1e-6)
    sel = on_cone & ~at_apex
    assert np.allclose(np.linalg.det(Fo[sel]), np.linalg.det(F[sel]), rtol=1e-5)
    # J_p J_E = J (one step from F = I: J = det F)
    jp = h.jp.to_numpy().astype(np.float64)
    assert np.allclose(jp * np.linalg.det(Fo), np.linalg.det(F), rtol=1e-5)


def test_sand_separation_is_stress_free_and_its_volume_comes_back(ti_f32):
    """Stretch by 3% (separation: projected to the apex, stress-free, the log-volume gained is
    remembered), then compress by 2%: still stress-free; compress by 2% more: only the remaining
    1% is elastic compression (Tampubolon et al. 2017 volume correction)."""
    m = mat(type="MPM.Sand", friction_angle=35.0)
    h = Harness(m, dim=3, n=4)
    s = np.exp(0.03 / 3)
    Fo, tau = h.run(np.eye(3) * s)
    assert np.abs(tau).max() == 0.0 and np.allclose(Fo, np.eye(3), atol=1e-6)
    vc = h.state()["sand_vc"]
    assert np.allclose(vc, 0.03, rtol=1e-5)
    Fo, tau = h.run(Fo @ (np.eye(3) * np.exp(-0.02 / 3)))
    assert np.abs(tau).max() == 0.0
    assert np.allclose(h.state()["sand_vc"], 0.01, rtol=1e-4)
    Fo, tau = h.run(Fo @ (np.eye(3) * np.exp(-0.02 / 3)))
    bulk = LAM + 2 * MU / 3
    assert np.allclose(np.log(np.linalg.det(Fo)), -0.01, rtol=1e-3)  # only 1% of it is elastic
    assert np.allclose(np.trace(tau, axis1=1, axis2=2) / 3, bulk * -0.01, rtol=1e-3)
    jp = h.jp.to_numpy()
    assert np.allclose(jp * np.linalg.det(Fo), math.exp(0.03 - 0.04), rtol=1e-5)  # J_p J_E = J


def test_sand_without_volume_correction_forgets_the_separation(ti_f32):
    m = mat(type="MPM.Sand", friction_angle=35.0, volume_correction=False)
    h = Harness(m, dim=3, n=4)
    Fo, _ = h.run(np.eye(3) * math.exp(0.01))
    Fo, _ = h.run(Fo @ (np.eye(3) * math.exp(-0.01 / 3)))
    assert np.allclose(np.log(np.linalg.det(Fo)), -0.01, rtol=1e-3)  # all of the compression is elastic


@pytest.mark.parametrize(
    "dim, cone, phi, mobilised, surface",
    [
        (2, "simple_shear", 30.0, 30.0, "drucker_prager"),  # the angle of repose is the friction angle
        (3, "simple_shear", 40.0, 40.0, "drucker_prager"),
        (2, "plane_strain", 30.0, math.degrees(math.atan(math.sin(math.radians(30.0)))), "drucker_prager"),
        (2, "simple_shear", 30.0, 30.0, "mohr_coulomb"),  # sin(phi_mc) = tan(phi): the same as the cone
        (3, "simple_shear", 40.0, 40.0, "mohr_coulomb"),
        (2, "plane_strain", 30.0, math.degrees(math.atan(math.sin(math.radians(30.0)))), "mohr_coulomb"),
        (2, "simple_shear", 30.0, 30.0, "matsuoka_nakai"),  # fitted at b = 0.5, where the flow puts it
        (3, "simple_shear", 40.0, 40.0, "matsuoka_nakai"),
        (2, "plane_strain", 30.0, math.degrees(math.atan(math.sin(math.radians(30.0)))), "matsuoka_nakai"),
    ],
)
def test_sand_in_steady_simple_shear_mobilises_the_cone_s_friction(
    ti_f32, dim, cone, phi, mobilised, surface
):
    """A flowing granular layer is in simple shear: compress (sigma_yy < 0), then shear in x-y by
    small steps of the velocity gradient, F <- (I + d gamma e_x e_y^T) F, each followed by the return
    mapping. With the zero-dilatancy flow the stress becomes steady with equal normal stresses, and
    the shear plane's friction tau_xy / -sigma_yy is the cone's 3 alpha / sqrt(2): tan(friction_angle)
    for the ``simple_shear`` cone, sin(phi) for ``plane_strain`` (Davis 1968, "Theories of plasticity
    and the failure of soil masses": tan phi* = sin phi cos psi / (1 - sin phi sin psi), psi = 0)."""
    m = mat(type="MPM.Sand", friction_angle=phi, cone=cone, yield_surface=surface)
    h = Harness(m, dim=dim, n=1)
    F = np.eye(dim)
    F[1, 1] = 0.995  # 0.5% compression: mean stress about -2 kPa
    Fo, tau = h.run(F)
    step = np.eye(dim)
    step[0, 1] = 2.0e-4
    for _ in range(400):  # total shear 0.08, many times the elastic shear strain at yield
        Fo, tau = h.run(step @ Fo)
    t = tau[0]
    ratio = t[0, 1] / -t[1, 1]
    assert math.degrees(math.atan(ratio)) == pytest.approx(mobilised, abs=0.3)
    assert t[0, 0] == pytest.approx(t[1, 1], rel=0.02)  # coaxial, steady: equal normal stresses


@pytest.mark.parametrize("dim,I_target", [(2, 0.05), (2, 0.5), (3, 0.3)])
def test_mu_i_sand_in_steady_simple_shear_mobilises_mu_of_I(ti_f32, dim, I_target):
    """With the mu(I) rheology a steady simple shear at rate gamma_dot under pressure p carries
    tau_xy / -sigma_yy = mu(I) = mu_s + dmu I / (I0 + I), I = gamma_dot d / sqrt(p / rho_s) (Jop,
    Forterre & Pouliquen 2006): the same shear test as above, with each shear increment taking dt."""
    phi, dmu, I0, d, rho_s = 30.0, 0.26, 0.279, 5.0e-4, 2500.0
    m = mat(
        type="MPM.Sand",
        friction_angle=phi,
        mu_i={"delta_mu": dmu, "I0": I0, "grain_diameter": d, "grain_density": rho_s},
    )
    h = Harness(m, dim=dim, n=1)
    F = np.eye(dim)
    F[1, 1] = 0.995  # 0.5% compression: mean stress about -2 kPa
    Fo, tau = h.run(F)
    p0 = -np.trace(tau[0]) / dim
    dgam = 2.0e-4
    gamma_dot = I_target * math.sqrt(p0 / rho_s) / d  # the shear rate that gives about I_target
    h.law.host_update(0.0, dgam / gamma_dot)
    step = np.eye(dim)
    step[0, 1] = dgam
    for _ in range(600):
        Fo, tau = h.run(step @ Fo)
    t = tau[0]
    p = -t[1, 1]
    I = gamma_dot * d / math.sqrt(p / rho_s)
    mu_s = math.tan(math.radians(phi))
    expected = mu_s + dmu * I / (I0 + I)
    assert t[0, 1] / p == pytest.approx(expected, rel=0.01)
    assert t[0, 1] / p > mu_s + 0.1 * dmu * I_target / (I0 + I_target)  # above the static cone


# ------------------------------------------------------------------------- sand, Mohr-Coulomb


def mc_yield(tau, sin_phi, apex=0.0):
    """Mohr-Coulomb f = (s1 - s3) + (s1 + s3 - 2 apex) sin(phi) (<= 0 admissible; principal Kirchhoff
    stresses s1 >= s3, tension positive) of 3x3 stresses."""
    sig = np.linalg.eigvalsh(tau)
    return (sig[:, 2] - sig[:, 0]) + (sig[:, 2] + sig[:, 0] - 2 * apex) * sin_phi


def principal_trials(mean_strain, lode_deg, radius):
    """3D F_E = diag(exp(eps)) with the log strains at a Lode angle (0: triaxial compression, the
    least-compressive two equal; 60: triaxial extension) and deviatoric radius |dev eps|, mean given."""
    th = np.radians(np.asarray(lode_deg, dtype=float))
    # deviatoric unit directions: compression (1, 1, -2) / sqrt 6 turned to extension (2, -1, -1) / sqrt 6
    a = np.array([1.0, 1.0, -2.0]) / math.sqrt(6)
    b = np.array([1.0, -1.0, 0.0]) / math.sqrt(2)
    d = np.cos(th)[:, None] * a + np.sin(th)[:, None] * b
    eps = mean_strain + radius * d
    return np.stack([np.diag(np.exp(e)) for e in eps]), eps


@pytest.fixture(scope="module")
def mc3(ti_f32):
    m = mat(type="MPM.Sand", friction_angle=30.0, yield_surface="mohr_coulomb")
    return m, Harness(m, dim=3, n=61)


def test_mohr_coulomb_sin_phi_follows_the_cone_fit():
    """simple_shear: the flowing layer's friction tan(phi) is sin(phi_mc) (Davis 1968, psi = 0); the
    other fits read friction_angle as the Mohr-Coulomb angle itself."""
    assert mat(
        type="MPM.Sand", friction_angle=30.0, yield_surface="mohr_coulomb"
    ).mc_sin_phi == pytest.approx(math.tan(math.radians(30.0)))
    m = mat(type="MPM.Sand", friction_angle=30.0, yield_surface="mohr_coulomb", cone="plane_strain")
    assert m.mc_sin_phi == pytest.approx(0.5)


def test_mohr_coulomb_bad_combinations_are_refused():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="friction_angle < 45"):
        mat(type="MPM.Sand", friction_angle=45.0, yield_surface="mohr_coulomb")
    with pytest.raises(ValidationError, match="drucker_prager"):
        mat(type="MPM.Sand", friction_angle=30.0, yield_surface="mohr_coulomb", mu_i={})
    mat(type="MPM.Sand", friction_angle=50.0, yield_surface="mohr_coulomb", cone="plane_strain")  # fine
    with pytest.raises(ValidationError, match="above 70 deg"):  # the edge returns' 2x2 solve, f32
        mat(type="MPM.Sand", friction_angle=44.0, yield_surface="mohr_coulomb")
    with pytest.raises(ValidationError, match="above 70 deg"):
        mat(type="MPM.Sand", friction_angle=80.0, yield_surface="mohr_coulomb", cone="plane_strain")


@pytest.mark.parametrize("cohesion", [0.0, 2.0e3])
def test_mohr_coulomb_sand_ends_on_or_inside_the_pyramid(ti_f32, cohesion):
    """Random trial F_E (compressive and tensile, large shear): the stress ends on or inside the
    pyramid, never beyond the apex c cot(phi_mc), the return keeps the volume (Tresca flow: no dilatancy)
    except at the apex, and J_p J_E = J."""
    m = mat(type="MPM.Sand", friction_angle=30.0, cohesion=cohesion, yield_surface="mohr_coulomb")
    h = Harness(m, dim=3, n=256)
    rng = np.random.default_rng(5)
    F = np.stack(
        [
            random_rotation(rng) @ np.diag(rng.uniform(0.95, 1.03, 3)) @ random_rotation(rng)
            for _ in range(h.n)
        ]
    )
    Fo, tau = h.run(F)
    apex = cohesion / math.tan(math.radians(30.0))  # the cone's apex, kept: the shear planes' cohesion
    f = mc_yield(tau, m.mc_sin_phi, apex)
    scale = np.abs(tau).max() + 1.0
    assert f.max() <= 1e-5 * scale
    on = f > -1e-5 * scale
    assert on.sum() > h.n // 4
    assert (np.trace(tau, axis1=1, axis2=2) / 3).max() <= apex * (1 + 1e-4) + 1e-3
    at_apex = np.isclose(np.linalg.svd(Fo, compute_uv=False).std(axis=1), 0.0, atol=1e-6)
    sel = on & ~at_apex
    assert sel.sum() > h.n // 4
    assert np.allclose(np.linalg.det(Fo[sel]), np.linalg.det(F[sel]), rtol=1e-5)
    jp = h.jp.to_numpy().astype(np.float64)
    assert np.allclose(jp * np.linalg.det(Fo), np.linalg.det(F), rtol=1e-5)
    # idempotent: the returned state is admissible, so a second return changes nothing
    Fo2, tau2 = h.run(Fo)
    assert np.allclose(Fo2, Fo, atol=2e-6)
    assert np.allclose(tau2, tau, atol=1e-4 * scale)


def test_mohr_coulomb_main_plane_and_edge_returns(mc3):
    """Trial strains at every Lode angle from triaxial compression (0 deg) to extension (60 deg), far
    outside: each returns onto the pyramid at the same mean stress, coaxially with the principal order
    kept, and its plastic strain is the Tresca flow of the active planes (KKT): on the main plane
    dgamma (1, 0, -1); a middle component only on an edge, positive on the compression edge
    (sigma_1 = sigma_2 after the return) and negative on the extension edge (sigma_2 = sigma_3). Near 0 and
    60 deg the main return would cross an edge, so the edge returns are exercised; exactly at 0 and 60 deg
    the stress stays triaxial."""
    m, h = mc3
    lode = np.linspace(0.0, 60.0, h.n)
    F, eps = principal_trials(-0.004, lode, 0.02)
    Fo, tau = h.run(F)
    off = Fo - np.stack([np.diag(np.diagonal(x)) for x in Fo])
    assert np.abs(off).max() < 1e-6  # coaxial: the principal axes are kept
    e_new = np.log(np.diagonal(Fo, axis1=1, axis2=2))
    sig = 2 * h.mu * e_new + h.lam * e_new.sum(1)[:, None]
    s = m.mc_sin_phi
    scale = np.abs(sig).max()
    f = (sig.max(1) - sig.min(1)) + (sig.max(1) + sig.min(1)) * s
    assert np.abs(f).max() < 2e-5 * scale  # on the pyramid
    assert np.allclose(e_new.sum(1), eps.sum(1), atol=2e-6)  # the volume is kept
    order = np.argsort(-eps, axis=1, kind="stable")  # trial order, sigma_1 (least compressive) first
    es = np.take_along_axis(e_new, order, 1)
    assert np.all(np.diff(es, axis=1) <= 2e-6)  # the order is kept
    d = np.take_along_axis(eps, order, 1) - es  # plastic strain, sorted
    tol = 2e-6
    assert np.all(d[:, 0] >= -tol) and np.all(d[:, 2] <= tol)
    edge_c = d[:, 1] > tol
    edge_e = d[:, 1] < -tol
    assert np.allclose(es[edge_c, 0], es[edge_c, 1], atol=tol)  # compression edge: sigma_1 = sigma_2
    assert np.allclose(es[edge_e, 1], es[edge_e, 2], atol=tol)  # extension edge: sigma_2 = sigma_3
    assert edge_c[0] and edge_e[-1]  # exact triaxial trials stay triaxial
    assert edge_c.sum() > 2 and edge_e.sum() > 2 and (~edge_c & ~edge_e).sum() > h.n // 2


def test_mohr_coulomb_friction_is_the_same_at_every_lode_angle(ti_f32):
    """The point of the pyramid: on it the largest shear stress over the normal stress on that plane
    (the Mohr circle's R / |centre|) is sin(phi_mc) = tan(30 deg) at any Lode angle, in triaxial
    compression (a conical heap's radially spreading surface flow) as in plane strain; the simple_shear
    Drucker-Prager cone gives the same in plane strain (b = 0.5) but only sin(25.4 deg) = 0.43 in
    triaxial compression."""
    target = math.tan(math.radians(30.0))
    ratios = {}
    for surface in ("mohr_coulomb", "drucker_prager"):
        m = mat(type="MPM.Sand", friction_angle=30.0, yield_surface=surface)
        h = Harness(m, dim=3, n=7)
        F, _ = principal_trials(-0.004, np.linspace(0.0, 60.0, 7), 0.02)
        _, tau = h.run(F)
        sig = np.linalg.eigvalsh(tau)
        ratios[surface] = (sig[:, 2] - sig[:, 0]) / -(sig[:, 2] + sig[:, 0])
    assert np.allclose(ratios["mohr_coulomb"], target, rtol=1e-4)
    dp = ratios["drucker_prager"]
    assert dp[3] == pytest.approx(target, rel=2e-3)  # b = 0.5 (Lode 30 deg): the cone's fit
    assert dp[0] == pytest.approx(math.sin(math.radians(25.4)), rel=2e-3)  # triaxial compression


@pytest.mark.parametrize("surface", ["mohr_coulomb", "matsuoka_nakai"])
def test_lode_dependent_2d_is_the_3d_law_in_plane_strain(ti_f32, surface):
    """2D is plane strain: the same in-plane F_E (F_zz = 1) gives the same stress as the 3D law,
    sigma_zz included, also where sigma_zz is the major or minor principal stress (plastic flow
    out of the plane), over a few steps of shear; for the pyramid and the Matsuoka-Nakai cone."""
    m = mat(type="MPM.Sand", friction_angle=30.0, cohesion=500.0, yield_surface=surface)
    h2 = Harness(m, dim=2, n=128)
    h3 = Harness(m, dim=3, n=128)
    rng = np.random.default_rng(11)
    F2 = np.stack(
        [
            random_rotation(rng, 2) @ np.diag(rng.uniform(0.96, 1.02, 2)) @ random_rotation(rng, 2)
            for _ in range(128)
        ]
    )
    F3 = np.zeros((128, 3, 3))
    F3[:, :2, :2] = F2
    F3[:, 2, 2] = 1.0
    for k in range(3):  # a few steps: the 2D law's eps_zz carries the out-of-plane plastic flow
        Fo2, tau2 = h2.run(F2)
        if k == 0:  # sigma_zz the major or minor stress: plastic flow out of the plane changed eps_zz
            assert (np.abs(h2.state()["sand_ezz"]) > 1e-6).sum() > 5
        tzz = h2.tzz.to_numpy().astype(np.float64)
        Fo3, tau3 = h3.run(F3)
        scale = np.abs(tau3).max()
        assert np.allclose(tau2, tau3[:, :2, :2], atol=2e-5 * scale)
        assert np.allclose(tzz, tau3[:, 2, 2], atol=2e-5 * scale)
        F2 = np.einsum("ij,njk->nik", np.array([[1.0, 0.004], [0.0, 0.999]]), Fo2)  # shear on
        F3 = Fo3.copy()  # its zz: the elastic out-of-plane stretch, as the 2D law's eps_zz
        F3[:, :2, :2] = F2


# ----------------------------------------------------------------------- sand, Matsuoka-Nakai


def mn_ratio(tau, apex=0.0):
    """I1 I2 / I3 of the principal stresses measured from the apex, compression positive (3x3 Kirchhoff);
    inf where a principal stress is not compressive (outside the Matsuoka-Nakai cone)."""
    c = apex - np.linalg.eigvalsh(tau)
    i1 = c.sum(1)
    i2 = c[:, 0] * c[:, 1] + c[:, 1] * c[:, 2] + c[:, 0] * c[:, 2]
    i3 = c.prod(1)
    return np.where(c.min(1) > 0, i1 * i2 / np.where(i3 > 0, i3, 1.0), np.inf)


def mobilised_sin(tau):
    """The Mohr circle's (sigma_1 - sigma_3) / -(sigma_1 + sigma_3) (cohesionless): sin of the Mohr-Coulomb
    angle the stress mobilises."""
    sig = np.linalg.eigvalsh(tau)
    return (sig[:, 2] - sig[:, 0]) / -(sig[:, 2] + sig[:, 0])


def test_matsuoka_nakai_k_follows_the_cone_fit():
    """K = I1 I2 / I3: at b = 0.5 (the simple shear's stress) the Mohr circle mobilises sin = x, K = 3 (3 -
    x^2) / (1 - x^2), x = tan(phi) (simple_shear) or sin(phi) (plane_strain); compression: Mohr-Coulomb
    phi in triaxial compression, K = (9 - sin^2) / (1 - sin^2). simple_shear at 30 deg: K = 12, a
    triaxial-compression angle of asin(sqrt(3 / 11)) = 31.48 deg."""
    k = mat(type="MPM.Sand", friction_angle=30.0, yield_surface="matsuoka_nakai").mn_k
    assert k == pytest.approx(12.0)
    assert math.degrees(math.asin(math.sqrt((k - 9) / (k - 1)))) == pytest.approx(31.482, abs=1e-3)
    m = mat(type="MPM.Sand", friction_angle=30.0, yield_surface="matsuoka_nakai", cone="plane_strain")
    assert m.mn_k == pytest.approx(3 * (3 - 0.25) / 0.75)
    m = mat(type="MPM.Sand", friction_angle=30.0, yield_surface="matsuoka_nakai", cone="compression")
    assert m.mn_k == pytest.approx((9 - 0.25) / 0.75)


def test_matsuoka_nakai_inner_radius_is_the_smallest_at_any_lode_angle():
    """The radius below which the return skips its cubic: the cone's radius at triaxial extension, the
    smallest root over every Lode angle of (9 - K) + (K - 3) / 2 u^2 + K w u^3 = 0."""
    w_max = 1.0 / (3.0 * math.sqrt(6.0))
    for phi, cone in ((30.0, "simple_shear"), (44.0, "simple_shear"), (20.0, "compression")):
        m = mat(type="MPM.Sand", friction_angle=phi, cone=cone, yield_surface="matsuoka_nakai")
        k = m.mn_k
        radii = []
        for w in np.linspace(-w_max, w_max, 41):
            r = np.roots([k * w, (k - 3) / 2, 0.0, 9 - k])
            r = r[np.isreal(r)].real
            radii.append(r[r > 0].min())
        assert m.mn_inner_radius == pytest.approx(min(radii), rel=1e-9)
        assert np.argmin(radii) == 40  # triaxial extension


def test_matsuoka_nakai_beside_a_45_deg_cone_in_one_law(ti_f32):
    """One compiled sand law for a Matsuoka-Nakai material and a cone of 45 deg sand (the default friction
    angle, for which the simple_shear K would be infinite): the cone's parameters are not asked for K."""
    import taichi as ti

    from simcli.solvers.mpm.laws import LAWS

    mn = mat(type="MPM.Sand", friction_angle=30.0, yield_surface="matsuoka_nakai")
    dp = mat(type="MPM.Sand", yield_surface="drucker_prager")  # in 3D auto would be Matsuoka-Nakai
    law = LAWS["sand"](3, ti.f32)
    law.allocate(4)
    law.allocate_materials([dp, mn])
    assert law.use_mn and law.mn_k.to_numpy().tolist() == [0.0, pytest.approx(12.0)]


def test_matsuoka_nakai_bad_combinations_are_refused():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="friction_angle < 45"):
        mat(type="MPM.Sand", friction_angle=45.0, yield_surface="matsuoka_nakai")
    with pytest.raises(ValidationError, match="friction_angle is not set"):
        mat(type="MPM.Sand", yield_surface="matsuoka_nakai")  # the default 45
    with pytest.raises(ValidationError, match="drucker_prager"):
        mat(type="MPM.Sand", friction_angle=30.0, yield_surface="matsuoka_nakai", mu_i={})
    mat(type="MPM.Sand", friction_angle=44.0, yield_surface="matsuoka_nakai")  # no edge solve: fine
    mat(type="MPM.Sand", friction_angle=60.0, yield_surface="matsuoka_nakai", cone="compression")


def test_the_default_yield_surface_is_matsuoka_nakai_fitted_in_compression_in_3d(ti_f32):
    """``yield_surface: auto`` (the default): in 3D Matsuoka-Nakai, fitted in triaxial compression unless the
    scene gives ``cone`` (a spreading 3D flow sits near triaxial compression, where the cone fitted to simple
    shear is weak); in 2D (a plane flow sits at b = 0.5) and with mu(I), the cone; with an explicit
    simple_shear fit at 45 deg and above (no finite K), the cone. The law compiles the resolved surface with
    the resolved fit's K, and the echoed scene names both."""
    import taichi as ti

    from simcli.scene.models import Scene, resolved_scene_dict
    from simcli.solvers.mpm.laws import LAWS

    assert mat(type="MPM.Sand", friction_angle=30.0).yield_surface == "auto"
    cases = [
        ({"friction_angle": 30.0}, 3, "matsuoka_nakai", "compression"),
        ({}, 3, "matsuoka_nakai", "compression"),  # the default 45 deg: K = 17 in compression
        ({"friction_angle": 30.0, "cone": "simple_shear"}, 3, "matsuoka_nakai", "simple_shear"),
        ({"friction_angle": 45.0, "cone": "simple_shear"}, 3, "drucker_prager", "simple_shear"),
        ({"friction_angle": 30.0, "cone": "plane_strain"}, 3, "matsuoka_nakai", "plane_strain"),
        ({"friction_angle": 30.0}, 2, "drucker_prager", "simple_shear"),
        ({"friction_angle": 30.0, "mu_i": {}}, 3, "drucker_prager", "simple_shear"),
        ({"friction_angle": 30.0, "yield_surface": "drucker_prager"}, 3, "drucker_prager", "simple_shear"),
        ({"friction_angle": 30.0, "yield_surface": "mohr_coulomb"}, 2, "mohr_coulomb", "simple_shear"),
    ]
    for kw, dim, surface, cone in cases:
        m = mat(type="MPM.Sand", **kw)
        used = m.resolved(dim)
        assert (used.yield_surface, used.cone) == (surface, cone), (kw, dim)
        law = LAWS["sand"](dim, ti.f32)
        law.allocate(2)
        law.allocate_materials([m])
        assert law.use_mn == (surface == "matsuoka_nakai"), (kw, dim)
        assert law.use_mc == (surface == "mohr_coulomb"), (kw, dim)
        assert law.alpha.to_numpy()[0] == pytest.approx(used.alpha, rel=1e-6)
        if surface == "matsuoka_nakai":
            assert law.mn_k.to_numpy()[0] == pytest.approx(used.mn_k, rel=1e-6)
    s30 = math.sin(math.radians(30.0))  # Matsuoka-Nakai in compression: K = (9 - sin^2) / (1 - sin^2)
    assert mat(type="MPM.Sand", friction_angle=30.0).resolved(3).mn_k == pytest.approx(
        (9 - s30**2) / (1 - s30**2)
    )
    for dim, surface, cone in ((3, "matsuoka_nakai", "compression"), (2, "drucker_prager", "simple_shear")):
        center = [0.5, 0.5, 0.5][:dim]
        scene = Scene.model_validate(
            {
                "sim": {"dim": dim},
                "entities": [
                    {
                        "name": "sand",
                        "material": {"type": "MPM.Sand", "friction_angle": 30.0},
                        "morph": {
                            "type": "Box" if dim == 3 else "Rectangle",
                            "center": center,
                            "size": [0.1] * dim,
                        },
                    }
                ],
            }
        )
        echoed = resolved_scene_dict(scene, "s")["entities"][0]["material"]
        assert (echoed["yield_surface"], echoed["cone"]) == (surface, cone)


@pytest.mark.parametrize("cohesion", [0.0, 2.0e3])
def test_matsuoka_nakai_sand_ends_on_or_inside_the_cone(ti_f32, cohesion):
    """Random trial F_E (compressive and tensile, large shear): the stress ends on or inside I1 I2 / I3 = K
    (from the apex c cot(phi), as the other surfaces'), the return keeps the volume (no dilatancy) except
    at the apex, J_p J_E = J, and a second return changes nothing (the returned state is admissible)."""
    m = mat(type="MPM.Sand", friction_angle=30.0, cohesion=cohesion, yield_surface="matsuoka_nakai")
    h = Harness(m, dim=3, n=256)
    rng = np.random.default_rng(5)
    F = np.stack(
        [
            random_rotation(rng) @ np.diag(rng.uniform(0.95, 1.03, 3)) @ random_rotation(rng)
            for _ in range(h.n)
        ]
    )
    Fo, tau = h.run(F)
    apex = cohesion / math.tan(math.radians(30.0))
    at_apex = np.isclose(np.linalg.svd(Fo, compute_uv=False).std(axis=1), 0.0, atol=1e-6)
    r = mn_ratio(tau[~at_apex], apex)
    assert np.isfinite(r).all() and r.max() <= m.mn_k * (1 + 1e-4)
    on = np.zeros(h.n, bool)
    on[~at_apex] = r > m.mn_k * (1 - 1e-4)
    assert on.sum() > h.n // 4
    assert (np.trace(tau, axis1=1, axis2=2) / 3).max() <= apex * (1 + 1e-4) + 1e-3
    assert np.allclose(np.linalg.det(Fo[on]), np.linalg.det(F[on]), rtol=1e-5)
    jp = h.jp.to_numpy().astype(np.float64)
    assert np.allclose(jp * np.linalg.det(Fo), np.linalg.det(F), rtol=1e-5)
    scale = np.abs(tau).max() + 1.0
    Fo2, tau2 = h.run(Fo)
    assert np.allclose(Fo2, Fo, atol=2e-6)
    assert np.allclose(tau2, tau, atol=1e-4 * scale)


def test_matsuoka_nakai_is_mohr_coulomb_at_compression_and_extension(ti_f32):
    """Trials far outside at every Lode angle from triaxial compression (0 deg) to extension (60 deg):
    each returns onto I1 I2 / I3 = K at the same mean stress, radially (the deviatoric strain scaled, its
    Lode angle kept: the cone's volume-keeping flow). With cone: compression (K from phi = 30 in triaxial
    compression) it mobilises exactly sin(30 deg) at 0 and 60 deg, the Mohr-Coulomb pyramid's triaxial
    corners, and more between them (the smooth cone lies outside the pyramid there); at b = 0.5 (Lode 30
    deg) sin = x with K = 3 (3 - x^2) / (1 - x^2)."""
    m = mat(type="MPM.Sand", friction_angle=30.0, yield_surface="matsuoka_nakai", cone="compression")
    h = Harness(m, dim=3, n=61)
    lode = np.linspace(0.0, 60.0, h.n)
    F, eps = principal_trials(-0.004, lode, 0.02)
    Fo, tau = h.run(F)
    e_new = np.log(np.diagonal(Fo, axis1=1, axis2=2))
    assert np.abs(Fo - np.stack([np.diag(np.diagonal(x)) for x in Fo])).max() < 1e-6  # coaxial
    assert np.allclose(e_new.sum(1), eps.sum(1), atol=2e-6)  # the volume is kept
    dev0 = eps - eps.mean(1, keepdims=True)
    dev1 = e_new - e_new.mean(1, keepdims=True)
    scale = (np.linalg.norm(dev1, axis=1) / np.linalg.norm(dev0, axis=1))[:, None]
    assert (scale < 0.9).all()  # every trial was far outside
    assert np.allclose(dev1, scale * dev0, atol=2e-6)  # radial: the Lode angle is kept
    assert np.allclose(mn_ratio(tau), m.mn_k, rtol=1e-4)  # on the cone
    sin_m = mobilised_sin(tau)
    assert sin_m[0] == pytest.approx(0.5, rel=1e-4) and sin_m[-1] == pytest.approx(0.5, rel=1e-4)
    assert (sin_m[1:-1] > 0.5).all()  # outside the pyramid of the same angle between its corners
    x = sin_m[30]  # Lode 30 deg, b = 0.5
    assert m.mn_k == pytest.approx(3 * (3 - x * x) / (1 - x * x), rel=1e-4)


def test_matsuoka_nakai_lies_between_the_cone_and_the_pyramid_in_compression(ti_f32):
    """Issue 23's point: all three fitted by the default simple_shear cone (a flowing layer, b = 0.5,
    carries tan 30 deg), in triaxial compression (under an impacting ball, a conical heap's flank) the
    cone is a Mohr-Coulomb material of 25.4 deg, the pyramid of 35.3 and Matsuoka-Nakai of 31.5; at b = 0.5
    all three mobilise sin = tan 30 deg."""
    got = {}
    for surface in ("drucker_prager", "matsuoka_nakai", "mohr_coulomb"):
        m = mat(type="MPM.Sand", friction_angle=30.0, yield_surface=surface)
        h = Harness(m, dim=3, n=3)
        F, _ = principal_trials(-0.004, np.array([0.0, 30.0, 60.0]), 0.02)
        _, tau = h.run(F)
        got[surface] = np.degrees(np.arcsin(mobilised_sin(tau)))
    b05 = math.degrees(math.asin(math.tan(math.radians(30.0))))
    for surface, tc in (("drucker_prager", 25.38), ("matsuoka_nakai", 31.48), ("mohr_coulomb", 35.26)):
        assert got[surface][0] == pytest.approx(tc, abs=0.02), surface
        assert got[surface][1] == pytest.approx(b05, abs=0.02), surface
    assert got["matsuoka_nakai"][2] == pytest.approx(31.48, abs=0.02)  # extension: Mohr-Coulomb's again


def test_matsuoka_nakai_is_elastic_inside(ti_f32):
    """Trials inside the cone (a small deviator under compression, every Lode angle) are left alone."""
    m = mat(type="MPM.Sand", friction_angle=30.0, yield_surface="matsuoka_nakai")
    h = Harness(m, dim=3, n=13)
    F, eps = principal_trials(-0.004, np.linspace(0.0, 60.0, h.n), 0.002)
    Fo, tau = h.run(F)
    assert np.allclose(Fo, F, atol=1e-7)
    assert (mn_ratio(tau) < m.mn_k * 0.99).all()


def test_mu_i_needs_the_simple_shear_cone():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="simple_shear"):
        mat(type="MPM.Sand", cone="plane_strain", mu_i={})


# ------------------------------------------------------------------------ liquid, muscle


@pytest.mark.parametrize("dim", [2, 3])
def test_liquid_keeps_only_the_volume(ti_f32, dim):
    h = Harness(mat(type="MPM.Liquid"), dim=dim, n=16)
    rng = np.random.default_rng(6)
    F = np.stack(
        [
            random_rotation(rng, dim) @ np.diag(rng.uniform(0.8, 1.2, dim)) @ random_rotation(rng, dim)
            for _ in range(h.n)
        ]
    )
    Fo, tau = h.run(F)
    J = np.linalg.det(F)
    assert np.allclose(Fo, J[:, None, None] ** (1 / dim) * np.eye(dim), rtol=1e-5, atol=1e-6)
    lam = mat(type="MPM.Liquid").lam
    assert np.allclose(tau, (lam * J * (J - 1))[:, None, None] * np.eye(dim), rtol=1e-4, atol=1e-2)


@pytest.mark.parametrize("dim", [2, 3])
def test_liquid_without_tension_cuts_the_pressure_off_at_zero(ti_f32, dim):
    """tension: false: p = lambda max(1 - J, 0); compressed particles keep the pressure they had, expanded
    ones carry none (stress, tau_zz in 2D and the energy density alike)."""
    h = Harness(mat(type="MPM.Liquid", tension=False), dim=dim, n=16)
    J = np.linspace(0.9, 1.1, h.n)
    F = np.stack([np.eye(dim) * j ** (1 / dim) for j in J])
    _, tau = h.run(F)
    lam = mat(type="MPM.Liquid").lam
    expect = lam * J * np.minimum(J - 1, 0)
    assert np.allclose(tau, expect[:, None, None] * np.eye(dim), rtol=1e-4, atol=1e-2)
    assert np.allclose(h.tzz.to_numpy(), expect, rtol=1e-4, atol=1e-2)
    assert (tau[J > 1.0001] == 0).all() and (np.diagonal(tau, axis1=1, axis2=2)[J < 0.9999] < 0).all()


def test_viscous_liquid_stress_is_2_mu_dev_D(ti_f32):
    eta = 2.5
    h = Harness(mat(type="MPM.Liquid", viscous=True, mu=eta), dim=3, n=8)
    rng = np.random.default_rng(7)
    C = rng.normal(size=(h.n, 3, 3)).astype(np.float32)
    h.C.from_numpy(C)
    _, tau = h.run(np.eye(3), plastic=False)
    D = 0.5 * (C + C.transpose(0, 2, 1))
    ref = 2 * eta * (D - np.eye(3) * (np.trace(D, axis1=1, axis2=2) / 3)[:, None, None])
    assert np.allclose(tau, ref, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("model", ["neohooken", "corotation"])
def test_muscle_active_stress_along_the_fibre(ti_f32, model):
    f0 = np.array([1.0, 2.0, 2.0]) / 3.0
    m = mat(
        type="MPM.Muscle",
        model=model,
        fiber_direction=f0.tolist(),
        groups=[{"actuation": {"type": "constant", "value": 0.1}}],
    )
    h = Harness(m, dim=3, n=8)
    h.law.host_update(0.0, 1.0e-3)
    rng = np.random.default_rng(8)
    F = np.stack([random_rotation(rng) @ np.diag(rng.uniform(0.9, 1.1, 3)) for _ in range(h.n)])
    _, tau_on = h.run(F, plastic=False)
    h.law._set_actuation(h.ti.Vector([0.0]))
    _, tau_off = h.run(F, plastic=False)
    a = F @ f0
    ref = 0.1 * m.E * a[:, :, None] * a[:, None, :]
    assert np.allclose(tau_on - tau_off, ref, rtol=1e-4, atol=1e-3)
