"""FEM constitutive models against finite differences (f64, in a subprocess: the test process
runs Taichi in f32): P = dpsi/dF, dP/dF = dP/dF (unprojected), the projected dP/dF is positive
semi-definite, zero stress at rest and rotated rest, and every model linearises to Hooke's law."""

import json
import subprocess
import sys

import pytest

SCRIPT = r"""
import json, numpy as np
from simcli.backend import init_taichi
init_taichi("cpu", "f64")
import taichi as ti
from simcli.solvers.fem.models import LAWS, apply_dP

N = 24
Fs = ti.Matrix.field(3, 3, ti.f64, shape=N)
psi = ti.field(ti.f64, shape=N)
P = ti.Matrix.field(3, 3, ti.f64, shape=N)
H = ti.Matrix.field(3, 3, ti.f64, shape=(2, N, 9))

def kernels(law):
    @ti.kernel
    def run(mu: ti.f64, lam: ti.f64):
        for p in range(N):
            psi[p] = law.energy(Fs[p], mu, lam)
            P[p] = law.pk1(Fs[p], mu, lam)
        for p, kl in ti.ndrange(N, 9):  # column kl of dP/dF: dP for dF = E_kl
            E = ti.Matrix.zero(ti.f64, 3, 3)
            E[kl // 3, kl % 3] = 1.0
            U, V, Hs, ls, lt = law.hessian(Fs[p], mu, lam, False)
            H[0, p, kl] = apply_dP(U, V, Hs, ls, lt, E)
            U2, V2, Hs2, ls2, lt2 = law.hessian(Fs[p], mu, lam, True)
            H[1, p, kl] = apply_dP(U2, V2, Hs2, ls2, lt2, E)
    def call(mu, lam):
        run(mu, lam)
    return call

def rot(rng):
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q @ np.diag(np.sign(np.diag(R)))
    if np.linalg.det(Q) < 0: Q[:, 0] *= -1
    return Q

rng = np.random.default_rng(3)
F = []
for p in range(N):
    s = rng.uniform(0.6, 1.5, 3)
    if p % 6 == 5: s[2] *= -0.5  # inverted
    if p % 6 == 4: s[1] = s[0]   # repeated singular values
    F.append(rot(rng) @ np.diag(s) @ rot(rng))
F = np.array(F)
mu, lam = 3.0e4, 5.0e4
out = {}
for name, law in LAWS.items():
    run = kernels(law)
    def ev(Fa):
        Fs.from_numpy(Fa); run(mu, lam)
        Hn = H.to_numpy()  # (2, N, kl, i, j) -> (2, N, 3i+j, kl)
        return psi.to_numpy(), P.to_numpy(), Hn.reshape(2, N, 9, 9).transpose(0, 1, 3, 2)
    e0, P0, H0 = ev(F)
    h = 1e-6
    errP, errH = 0.0, 0.0
    dpsi = np.zeros_like(P0); dP = np.zeros((N, 9, 9))
    for k in range(3):
        for l in range(3):
            Fp = F.copy(); Fp[:, k, l] += h
            Fm = F.copy(); Fm[:, k, l] -= h
            ep, Pp, _ = ev(Fp); em, Pm, _ = ev(Fm)
            dpsi[:, k, l] = (ep - em) / (2 * h)
            dP[:, :, 3 * k + l] = ((Pp - Pm) / (2 * h)).reshape(N, 9)
    scaleP = np.abs(P0).max() + mu
    scaleH = np.abs(dP).max()
    errP = float(np.abs(dpsi - P0).max() / scaleP)
    errH = float(np.abs(dP - H0[0]).max() / scaleH)
    eig = np.linalg.eigvalsh(0.5 * (H0[1] + H0[1].transpose(0, 2, 1)))
    sym = float(np.abs(H0[0] - H0[0].transpose(0, 2, 1)).max() / scaleH)
    # rest and rotated rest
    R = rot(rng)
    e_r, P_r, H_r = ev(np.array([np.eye(3), R] + [np.eye(3)] * (N - 2)))
    # small strain: P(I + eps) ~ 2 mu eps + lam tr eps I (Lame as given, i.e. after lame_for)
    eps = 1e-6 * rng.normal(size=(3, 3)); eps = 0.5 * (eps + eps.T)
    _, P_s, _ = ev(np.array([np.eye(3) + eps] * N))
    from simcli.solvers.fem.models import lame_for
    m2, l2 = lame_for(name, mu, lam)
    # the kernel got (mu, lam); Hooke with the Lame parameters that map to them
    lam_lame = {"stable_neohookean": lam - mu, "neohookean_decoupled": lam - 2 * mu / 3}.get(name, lam)
    hooke = 2 * mu * eps + lam_lame * np.trace(eps) * np.eye(3)
    out[name] = dict(errP=errP, errH=errH, sym=sym, min_eig=float(eig.min() / scaleH),
                     rest=float(np.abs(P_r[0]).max() / mu), rest_rot=float(np.abs(P_r[1]).max() / mu),
                     e_rest_rot=float(abs(e_r[1]) / mu),
                     hooke=float(np.abs(P_s[0] - hooke).max() / np.abs(hooke).max()))
print("RESULT " + json.dumps(out))
"""


MODELS = ["linear", "linear_corotated", "stable_neohookean", "neohookean", "neohookean_decoupled"]


@pytest.fixture(scope="module")
def fd(tmp_path_factory):
    script = tmp_path_factory.mktemp("fem_fd") / "fd.py"  # Taichi needs kernels' source in a file
    script.write_text(SCRIPT)
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("RESULT "))
    return json.loads(line[7:])


@pytest.mark.parametrize("model", MODELS)
def test_stress_is_energy_gradient(fd, model):
    assert fd[model]["errP"] < 1e-6


@pytest.mark.parametrize("model", MODELS)
def test_hessian_is_stress_derivative(fd, model):
    assert fd[model]["errH"] < 1e-5
    assert fd[model]["sym"] < 1e-9


@pytest.mark.parametrize("model", MODELS)
def test_projected_hessian_is_psd(fd, model):
    assert fd[model]["min_eig"] > -1e-9


@pytest.mark.parametrize("model", MODELS)
def test_zero_stress_at_rest_and_hooke_at_small_strain(fd, model):
    assert fd[model]["rest"] < 1e-12
    assert fd[model]["hooke"] < 1e-4
    if model != "linear":  # the rotation-invariant models: no stress in a rotated rest state
        assert fd[model]["rest_rot"] < 1e-9
        assert fd[model]["e_rest_rot"] < 1e-9
    else:  # linear elasticity is not rotation invariant: a rotation "stresses" it
        assert fd[model]["rest_rot"] > 1e-3
