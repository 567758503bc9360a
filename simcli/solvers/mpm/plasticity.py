"""Plastic MPM laws: von Mises and clamped elasto-plasticity, Drucker-Prager sand, snow.

All four work on the singular values of the trial elastic deformation gradient
F_E = U diag(s) V^T (3D: Jacobi eigen-decomposition of F F^T warm-started from the particle's U of the
last substep, ``svd3_via_b_warm``; 2D: ``ti.svd``), after the update F <- (I + dt C) F of g2p:

* ``von_mises`` (``MPM.ElastoPlastic``, ``use_von_mises: true``): Hencky elasticity
  tau = U (2 mu eps + lambda tr(eps) I) U^T, eps = log(s), and J2 plasticity by radial return on
  the deviatoric Hencky strain (Simo 1992; the return is exact for Hencky elasticity because the
  deviatoric Kirchhoff stress is 2 mu dev(eps)). The von Mises equivalent *Cauchy* stress
  sqrt(3/2) |dev tau| / J_E is kept <= sigma_y: in strain space |dev eps| <= sqrt(2/3) sigma_y J_E /
  (2 mu). Plastic flow keeps the volume, so J_E = exp(tr eps) is not changed by the return and
  the bound is exact: uniaxial stress saturates at sigma_y, pure shear at sigma_y / sqrt(3).
  (Genesis bounds |dev eps| by sigma_y / (2 mu), which lets uniaxial stress reach
  sqrt(3/2) sigma_y.)
* ``clamp`` (``use_von_mises: false``): s clamped into [1 - theta_c, 1 + theta_s] (Stomakhin
  et al. 2013 without hardening), fixed corotated elasticity with R = U V^T.
* ``snow``: the same clamp, J_p <- J_p prod(s / s_clamped), and mu, lambda scaled by
  exp(xi (1 - J_p)) (Stomakhin et al. 2013, eq. 1-3).
* ``sand``: Drucker-Prager on the Hencky strain (Klar et al. 2016, sec. 6.3 and eq. 26-28), the
  cone's slope alpha fitted to the friction angle by ``MPMSand.cone`` (config.py; by default so that
  steady simple shear, a flowing layer, mobilises tan(phi): the return below keeps the volume, and with
  that zero-dilatancy flow a cone fitted to Mohr-Coulomb phi would mobilise only sin(phi), Davis 1968),
  cohesion by moving the cone's apex to the tensile mean stress c / tan(phi), and the volume
  correction of Tampubolon et al. 2017 (sec. 4.3.2): the log-volume a particle gains when it is
  projected to the apex (grains separating) is remembered and given back before it resists
  compression again. ``yield_surface: mohr_coulomb`` replaces the cone by the Mohr-Coulomb pyramid
  (sin(phi_mc) = tan(phi) for the simple_shear fit, so a flowing layer carries tan(phi) at any Lode
  angle, where the cone does only at b = 0.5), returned exactly in principal strain with the Tresca
  (zero-dilatancy) flow: main plane, edges, apex (``SandLaw.mohr_coulomb_return``).
  ``yield_surface: matsuoka_nakai`` the smooth cone I1 I2 / I3 = K (Matsuoka & Nakai 1974, "Stress-deformation
  and strength characteristics of soil under three different principal stresses", Proc. JSCE 232, 59-70),
  Mohr-Coulomb at triaxial compression and extension, outside it between them, fitted at b = 0.5 as the
  cone; returned radially in the deviatoric plane (the cone's flow; ``SandLaw.matsuoka_nakai_return``).
  The default ``yield_surface: auto`` is Matsuoka-Nakai fitted in triaxial compression in 3D (no mu(I)) and
  the cone fitted to simple shear in 2D (``MPMSand.resolved``).

Each law computes the Kirchhoff stress from the same decomposition and stores it per particle
(``stores_stress``): p2g reads it, so F is decomposed once per substep. J_p, where tracked, obeys
J_p J_E = J exactly up to round-off (clamp, snow, sand).

2D is plane strain (F_zz = 1). The Hencky laws (von Mises, sand) keep the out-of-plane elastic
log strain eps_zz per particle: plastic flow may change it (the total F_zz stays 1, so the
plastic one compensates), and the return mappings work on the three principal strains
(eps_1, eps_2, eps_zz), exactly as a 3D body in plane strain would; a 2D von Mises bar therefore
yields at the same stresses as a 3D one. The clamp laws (clamp, snow) clamp the two in-plane
singular values only (as Stomakhin et al. in 2D); their out-of-plane stress is lambda J (J - 1).
"""

import math
from typing import Any, ClassVar

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.solvers.mpm.constitutive import (
    ConstitutiveLaw,
    _np_dtype,
    identity_quaternions,
    mat_to_quat,
    quat_to_mat,
)
from simcli.solvers.taichi_funcs import jacobi_rotation

with stdout_to_stderr():
    import taichi as ti

_MN_W_MAX = 1.0 / (3.0 * math.sqrt(6.0))  # |n_1 n_2 n_3| of a unit deviatoric vector: triaxial states


@ti.func
def principal(U, s, V):
    """U diag(s) V^T."""
    A = U * 0.0
    for i in ti.static(range(s.n)):
        for j in ti.static(range(s.n)):
            acc = U[i, 0] * s[0] * V[j, 0]
            for k in ti.static(range(1, s.n)):
                acc += U[i, k] * s[k] * V[j, k]
            A[i, j] = acc
    return A


@ti.func
def jacobi_eig3(A, sweeps):
    """Eigen-decomposition of a symmetric 3x3 matrix by cyclic Jacobi rotations (Golub & Van Loan,
    Matrix Computations, sec. 8.5): returns (eigenvalues as a vector, orthogonal Q) with
    A = Q diag(lambda) Q^T. Quadratic convergence; near-diagonal input (the common small-strain
    case) needs one sweep, and repeated eigenvalues need none: robust where closed forms are not."""
    Q = A * 0.0
    for k in ti.static(range(3)):
        Q[k, k] = 1.0
    for _ in range(sweeps):  # a run-time loop: a quarter of the code to compile, and an early exit
        off = A[0, 1] * A[0, 1] + A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2]
        diag = A[0, 0] * A[0, 0] + A[1, 1] * A[1, 1] + A[2, 2] * A[2, 2]
        if off <= 1.0e-14 * diag:  # diagonal to f32 round-off (and to 1e-7 in f64)
            break
        for p, q, r in ti.static(((0, 1, 2), (0, 2, 1), (1, 2, 0))):
            apq = A[p, q]
            if ti.abs(apq) > 1.0e-30:
                t, c, s = jacobi_rotation(A[p, p], A[q, q], apq)
                arp = c * A[r, p] - s * A[r, q]
                arq = s * A[r, p] + c * A[r, q]
                A[p, p] = A[p, p] - t * apq
                A[q, q] = A[q, q] + t * apq
                A[p, q] = 0.0
                A[q, p] = 0.0
                A[r, p] = arp
                A[p, r] = arp
                A[r, q] = arq
                A[q, r] = arq
                for k in ti.static(range(3)):
                    qkp = Q[k, p]
                    qkq = Q[k, q]
                    Q[k, p] = c * qkp - s * qkq
                    Q[k, q] = s * qkp + c * qkq
    return ti.Vector([A[0, 0], A[1, 1], A[2, 2]]), Q


@ti.func
def _svd_from_eig(F, lam, U):
    """F = U diag(s) V^T from the eigenvectors U (a rotation) and eigenvalues lam of F F^T."""
    s = ti.sqrt(ti.max(lam, 0.0))
    if F.determinant() < 0.0:
        k = 0
        if s[1] < s[k]:
            k = 1
        if s[2] < s[k]:
            k = 2
        s[k] = -s[k]
    W = U.transpose() @ F  # = diag(s) V^T
    for i in ti.static(range(3)):
        si = s[i]
        if ti.abs(si) < 1.0e-12:
            si = 1.0e-12
        for j in ti.static(range(3)):
            W[i, j] = W[i, j] / si
    return U, s, W.transpose()


@ti.func
def svd3_via_b(F):
    """F = U diag(s) V^T with U, V rotations, from the eigen-decomposition of b = F F^T (four Jacobi
    sweeps): the eigenvectors are U, s = sqrt(eigenvalues), and V^T = diag(1/s) U^T F. The smallest
    s is negative when det F < 0 (Taichi's ti.svd convention). On a 2-core CPU about half the cost of
    ti.svd for a general F and far less where F F^T is already diagonal (sweeps stop early: grains
    at the cone's apex, unrotated bodies); the same results to f32 round-off."""
    lam, U = jacobi_eig3(F @ F.transpose(), 4)
    if U.determinant() < 0.0:
        for k in ti.static(range(3)):
            U[k, 2] = -U[k, 2]
    return _svd_from_eig(F, lam, U)


@ti.func
def svd3_via_b_warm(F, U0):
    """``svd3_via_b`` started from a guess U0 (a rotation) of U: Jacobi on U0^T (F F^T) U0, then
    U = U0 Q. With U0 the particle's U of the previous substep the matrix is nearly diagonal, so the
    sweeps stop after one, however far the material has turned: a body in rotation (sand stirred by a
    paddle, a spinning plastic block) costs what it costs at rest, where the cold start needs three or
    four sweeps. The same decomposition to f32 round-off (the sweeps stop at the same off-diagonal
    tolerance); U stays a rotation (a product of rotations)."""
    b = U0.transpose() @ (F @ F.transpose()) @ U0
    lam, Q = jacobi_eig3(b, 4)
    return _svd_from_eig(F, lam, U0 @ Q)


@ti.func
def singular_values(S):
    return ti.Vector([S[i, i] for i in ti.static(range(S.n))])


@ti.data_oriented
class _SVDPlasticLaw(ConstitutiveLaw):
    """Shared host side: the stored Kirchhoff stress and (optionally) J_p per particle."""

    plastic: ClassVar[bool] = True
    stores_stress: ClassVar[bool] = True
    material_type: ClassVar[str] = ""

    plane_strain_zz: ClassVar[bool] = False  # 2D: keeps the out-of-plane elastic log strain

    def allocate(self, n: int) -> None:
        self.n = n
        self.tau = ti.Matrix.field(self.dim, self.dim, self.dtype, shape=n)
        self.Jp = ti.field(self.dtype, shape=n) if self.tracks_jp else None
        self.ezz = ti.field(self.dtype, shape=n) if (self.plane_strain_zz and self.dim == 2) else None
        # 3D: the quaternion of each particle's last U, the warm start of the next decomposition
        self.Uq = ti.Vector.field(4, self.dtype, shape=n) if self.dim == 3 else None

    def _np(self):
        return _np_dtype(self.dtype)

    def _state_fields(self) -> dict:
        fields = {f"{self.key}_tau": self.tau}
        if self.Jp is not None:
            fields[f"{self.key}_Jp"] = self.Jp
        if self.ezz is not None:
            fields[f"{self.key}_ezz"] = self.ezz
        if self.Uq is not None:
            fields[f"{self.key}_Uq"] = self.Uq
        return fields

    def state_names(self) -> list[str]:
        return list(self._state_fields())

    def init_state(self) -> None:
        self.tau.from_numpy(np.zeros((self.n, self.dim, self.dim), self._np()))
        if self.Jp is not None:
            self.Jp.from_numpy(np.ones(self.n, self._np()))
        if self.ezz is not None:
            self.ezz.from_numpy(np.zeros(self.n, self._np()))
        if self.Uq is not None:
            self.Uq.from_numpy(identity_quaternions(self.n, self._np()))

    def get_state(self) -> dict[str, np.ndarray]:
        return {k: f.to_numpy() for k, f in self._state_fields().items()}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        for k, f in self._state_fields().items():
            if f is self.Uq and k not in state:
                # a checkpoint from before the warm start: start cold (the same decomposition to round-off)
                f.from_numpy(identity_quaternions(self.n, self._np()))
                continue
            f.from_numpy(np.ascontiguousarray(state[k], dtype=self._np()))

    def _param(self, materials: list, getter) -> Any:
        """A per-material parameter field, filled for the materials of this law."""
        fld = ti.field(self.dtype, shape=max(1, len(materials)))
        arr = np.zeros(max(1, len(materials)), self._np())
        for k, m in enumerate(materials):
            if self.uses(m):
                arr[k] = getter(m)
        fld.from_numpy(arr)
        return fld

    def uses(self, material: Any) -> bool:
        from simcli.solvers.mpm.constitutive import law_key

        return law_key(material) == self.key

    def bind(self, solver: Any) -> None:
        self.mid = solver.mid
        self.C = solver.C

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        return self.tau[p]

    @ti.func
    def decompose(self, F):
        """(U, singular values s, V) with F = U diag(s) V^T: Jacobi on F F^T in 3D, ti.svd in 2D."""
        U = F * 0.0
        V = F * 0.0
        s = ti.Vector.zero(self.dtype, self.dim)
        if ti.static(self.dim == 3):
            U, s, V = svd3_via_b(F)
        else:
            U, S, V = ti.svd(F, self.dtype)
            s = singular_values(S)
        return U, s, V

    @ti.func
    def decompose_warm(self, p, F):
        """``decompose`` for the return mapping: in 3D warm-started from particle p's U of the last
        substep, which it then stores (outputs use the cold ``decompose`` and leave the state alone)."""
        U = F * 0.0
        V = F * 0.0
        s = ti.Vector.zero(self.dtype, self.dim)
        if ti.static(self.dim == 3):
            U, s, V = svd3_via_b_warm(F, quat_to_mat(self.Uq[p]))
            self.Uq[p] = mat_to_quat(U)
        else:
            U, s, V = self.decompose(F)
        return U, s, V

    @ti.func
    def plastic_J(self, p):
        jp = 1.0
        if ti.static(self.tracks_jp):
            jp = self.Jp[p]
        return jp

    @ti.func
    def elastic_J(self, p, J):
        """det F_E; 2D: times the out-of-plane elastic stretch exp(eps_zz)."""
        r = J
        if ti.static(self.plane_strain_zz and self.dim == 2):
            r *= ti.exp(self.ezz[p])
        return r

    # ---- Hencky laws: three principal log strains (2D: the third is eps_zz, plane strain)
    @ti.func
    def log_strains(self, p, s, floor):
        """(eps_1, eps_2, eps_3) of the trial F_E; 2D: (eps_1, eps_2, eps_zz)."""
        e = ti.log(ti.max(ti.abs(s), floor))
        r = ti.Vector.zero(self.dtype, 3)
        if ti.static(self.dim == 3):
            r = e
        else:
            r = ti.Vector([e[0], e[1], self.ezz[p]])
        return r

    @ti.func
    def in_plane(self, e3):
        r = ti.Vector.zero(self.dtype, self.dim)
        for i in ti.static(range(self.dim)):
            r[i] = e3[i]
        return r

    @ti.func
    def store_hencky(self, p, U, e3, mu, lam):
        """Store the Kirchhoff stress U diag(2 mu eps + lambda tr eps) U^T (in-plane part in 2D)
        and, in 2D, the out-of-plane elastic strain."""
        tr = e3.sum()
        self.tau[p] = principal(U, 2.0 * mu * self.in_plane(e3) + lam * tr, U)
        if ti.static(self.dim == 2):
            self.ezz[p] = e3[2]

    @ti.func
    def hencky_energy(self, p, F, mu, lam):
        _U, sv, _V = self.decompose(F)
        eps = self.log_strains(p, sv, 1.0e-6)
        tr = eps.sum()
        return mu * eps.dot(eps) + 0.5 * lam * tr * tr

    @ti.func
    def hencky_tau_zz(self, p, J, mu, lam):
        r = 0.0
        if ti.static(self.dim == 2):
            ezz = self.ezz[p]
            r = 2.0 * mu * ezz + lam * (ti.log(ti.max(J, 1.0e-6)) + ezz)
        return r

    @ti.func
    def corotated_principal_tau(self, U, s, mu, lam):
        """Fixed corotated Kirchhoff stress for F = U diag(s) V^T, R = U V^T:
        2 mu (F - R) F^T + lambda J (J - 1) I = U diag(2 mu (s - 1) s + lambda J (J - 1)) U^T."""
        J = 1.0
        for i in ti.static(range(s.n)):
            J *= s[i]
        return principal(U, 2.0 * mu * (s - 1.0) * s + lam * J * (J - 1.0), U)

    @ti.func
    def corotated_energy(self, F, J, mu, lam):
        _U, s, _V = self.decompose(F)
        return mu * (s - 1.0).dot(s - 1.0) + 0.5 * lam * (J - 1.0) ** 2


@ti.data_oriented
class VonMisesLaw(_SVDPlasticLaw):
    """``MPM.ElastoPlastic`` with ``use_von_mises: true``: Hencky elasticity + J2 radial return."""

    key = "von_mises"
    plane_strain_zz = True

    def allocate_materials(self, materials: list) -> None:
        self.n_materials = len(materials)
        self.yield_stress = self._param(materials, lambda m: m.von_mises_yield_stress)

    @ti.func
    def return_mapping(self, p, F, mid, mu, lam):
        U, s, V = self.decompose_warm(p, F)
        # an inverted or nearly collapsed particle: no logarithm of s <= 0 (as Genesis: floor 0.05)
        eps = self.log_strains(p, s, 0.05)
        changed = False
        for i in ti.static(range(self.dim)):
            if s[i] < 0.05:
                changed = True
        tr = eps.sum()
        ehat = eps - tr / 3.0
        norm = ehat.norm()
        # |dev eps| <= sqrt(2/3) sigma_y J_E / (2 mu): von Mises Cauchy stress <= sigma_y, J_E = exp(tr)
        radius = ti.sqrt(2.0 / 3.0) * self.yield_stress[mid] * ti.exp(tr) / (2.0 * mu)
        if norm > radius:
            eps = tr / 3.0 + (radius / norm) * ehat
            changed = True
        Fn = F
        if changed:
            Fn = principal(U, ti.exp(self.in_plane(eps)), V)
        self.store_hencky(p, U, eps, mu, lam)
        return Fn

    @ti.func
    def tau_zz(self, p, F, J, mu, lam):
        return self.hencky_tau_zz(p, J, mu, lam)

    @ti.func
    def energy_density(self, p, F, J, mu, lam):
        return self.hencky_energy(p, F, mu, lam)


@ti.data_oriented
class ClampLaw(_SVDPlasticLaw):
    """``MPM.ElastoPlastic`` with ``use_von_mises: false``: clamped singular values, corotated."""

    key = "clamp"
    tracks_jp = True

    def allocate_materials(self, materials: list) -> None:
        self.n_materials = len(materials)
        self.lower = self._param(materials, lambda m: 1.0 - m.yield_lower)
        self.upper = self._param(materials, lambda m: 1.0 + m.yield_higher)

    @ti.func
    def clamp(self, p, F, mid):
        """Clamp the singular values; J_p takes the volume the clamp removes from F_E."""
        U, s, V = self.decompose_warm(p, F)
        lo = self.lower[mid]
        hi = self.upper[mid]
        sc = ti.min(ti.max(s, lo), hi)
        ratio = 1.0
        for i in ti.static(range(self.dim)):
            # s <= 0 (inverted) cannot be a volume ratio: count it as a tiny positive one
            ratio *= ti.max(s[i], 1.0e-6) / sc[i]
        jp = self.Jp[p] * ratio
        self.Jp[p] = jp
        return U, sc, V, jp

    @ti.func
    def return_mapping(self, p, F, mid, mu, lam):
        U, sc, V, _jp = self.clamp(p, F, mid)
        self.tau[p] = self.corotated_principal_tau(U, sc, mu, lam)
        return principal(U, sc, V)

    @ti.func
    def tau_zz(self, p, F, J, mu, lam):
        return lam * (J - 1.0) * J

    @ti.func
    def energy_density(self, p, F, J, mu, lam):
        return self.corotated_energy(F, J, mu, lam)


@ti.data_oriented
class SnowLaw(ClampLaw):
    """``MPM.Snow``: the clamp of ``ClampLaw`` with hardening exp(xi (1 - J_p))."""

    key = "snow"
    hardens = True

    def allocate_materials(self, materials: list) -> None:
        super().allocate_materials(materials)
        self.xi = self._param(materials, lambda m: m.hardening)

    @ti.func
    def hardening(self, mid, jp):
        return ti.exp(self.xi[mid] * (1.0 - jp))

    @ti.func
    def return_mapping(self, p, F, mid, mu, lam):
        U, sc, V, jp = self.clamp(p, F, mid)
        h = self.hardening(mid, jp)
        self.tau[p] = self.corotated_principal_tau(U, sc, mu * h, lam * h)
        return principal(U, sc, V)

    @ti.func
    def tau_zz(self, p, F, J, mu, lam):
        return self.hardening(self.mid[p], self.Jp[p]) * lam * (J - 1.0) * J

    @ti.func
    def energy_density(self, p, F, J, mu, lam):
        h = self.hardening(self.mid[p], self.Jp[p])
        return self.corotated_energy(F, J, mu * h, lam * h)

    @ti.func
    def stiffness_factor(self, p):
        return self.hardening(self.mid[p], self.Jp[p])

    def max_stiffness_factor(self, materials: list) -> float:
        return max([math.exp(m.hardening) for m in materials if self.uses(m)] + [1.0])


@ti.data_oriented
class SandLaw(_SVDPlasticLaw):
    """``MPM.Sand``: Drucker-Prager (Klar et al. 2016), Mohr-Coulomb or Matsuoka-Nakai, cohesion, volume
    correction."""

    key = "sand"
    tracks_jp = True
    plane_strain_zz = True

    def resolve(self, material: Any) -> Any:
        """``material`` with ``yield_surface: auto`` resolved for this law's dimension (surface and fit)."""
        return material.resolved(self.dim) if hasattr(material, "resolved") else material

    def allocate(self, n: int) -> None:
        super().allocate(n)
        self.vc = ti.field(self.dtype, shape=n)  # log-volume gained while separated (Tampubolon 2017)

    def _state_fields(self) -> dict:
        return {**super()._state_fields(), "sand_vc": self.vc}

    def init_state(self) -> None:
        super().init_state()
        self.vc.from_numpy(np.zeros(self.n, self._np()))

    def allocate_materials(self, materials: list) -> None:
        materials = [self.resolve(m) for m in materials]  # auto's surface and fit, by dimension
        self.n_materials = len(materials)
        self.alpha = self._param(materials, lambda m: m.alpha)
        # mean Kirchhoff stress at the cone's apex: c cot(phi) (Mohr-Coulomb), 0 without cohesion
        self.apex = self._param(materials, lambda m: m.cohesion / math.tan(math.radians(m.friction_angle)))
        self.correct = self._param(materials, lambda m: 1.0 if m.volume_correction else 0.0)
        # Mohr-Coulomb (yield_surface: mohr_coulomb), compiled in only when a sand material asks for it
        self.use_mc = any(self.uses(m) and m.yield_surface == "mohr_coulomb" for m in materials)
        if self.use_mc:
            self.mc = self._param(materials, lambda m: 1.0 if m.yield_surface == "mohr_coulomb" else 0.0)
            self.mc_sin = self._param(materials, lambda m: m.mc_sin_phi)
        # Matsuoka-Nakai (yield_surface: matsuoka_nakai), compiled in only when a sand material asks for it
        self.use_mn = any(self.uses(m) and m.yield_surface == "matsuoka_nakai" for m in materials)
        if self.use_mn:

            def mn(getter):  # only the Matsuoka-Nakai materials' (a cone of 45 deg sand has no finite K)
                return self._param(
                    materials, lambda m: getter(m) if m.yield_surface == "matsuoka_nakai" else 0.0
                )

            self.mn = mn(lambda m: 1.0)
            self.mn_k = mn(lambda m: m.mn_k)
            # K - 9 (> 0) and (K - 3) / 2 from the host's float64: 9 - K loses digits in f32 near K = 9
            self.mn_km9 = mn(lambda m: m.mn_k - 9.0)
            self.mn_b = mn(lambda m: 0.5 * (m.mn_k - 3.0))
            self.mn_tol = 4.0 * float(np.finfo(self._np()).eps)  # Newton's relative step to stop at
            # the smallest radius (triaxial extension), a little inside: below it no cubic is solved
            self.mn_inner = mn(lambda m: m.mn_inner_radius * (1.0 - 1.0e-5))
        # mu(I) rheology (Jop et al. 2006), compiled in only when a sand material asks for it
        self.use_mu_i = any(self.uses(m) and getattr(m, "mu_i", None) is not None for m in materials)
        if self.use_mu_i:
            self.mu_s = self._param(materials, lambda m: math.tan(math.radians(m.friction_angle)))
            self.dmu = self._param(materials, lambda m: m.mu_i.delta_mu if m.mu_i is not None else 0.0)
            self.I0 = self._param(materials, lambda m: m.mu_i.I0 if m.mu_i is not None else 1.0)
            # I = k_I dgamma / sqrt(p): k_I = sqrt(2) d sqrt(rho_s) / dt, the dt part set per substep
            self.dsr = self._param(
                materials,
                lambda m: (
                    math.sqrt(2.0) * m.mu_i.grain_diameter * math.sqrt(m.grain_density)
                    if m.mu_i is not None
                    else 0.0
                ),
            )
            self.inv_dt = ti.field(self.dtype, shape=())
            self._last_dt = None

    def host_update(self, t: float, dt: float) -> None:
        if self.use_mu_i and dt != self._last_dt:  # a constant substep is uploaded once
            self.inv_dt[None] = 1.0 / dt
            self._last_dt = dt

    @ti.func
    def mu_i_projection(self, mid, b, A, pressure):
        """The plastic deviatoric strain increment dgamma of the mu(I) cone.

        Static cone: |ehat| - dgamma = A mu_s, so dgamma = b = |ehat| - A mu_s. With mu(I) the cone is
        |ehat| - dgamma = A mu(I), mu(I) = mu_s + dmu I / (I0 + I), I = k dgamma (the plastic shear rate
        gamma_dot = sqrt(2) dgamma / dt of a simple shear, times d / sqrt(p / rho_s)): the positive root
        of k dgamma^2 + (I0 + k (A dmu - b)) dgamma - b I0 = 0, in [0, b]. As p -> 0 it tends to
        b - A dmu (friction mu_2), as k -> 0 to b (mu_s)."""
        k = self.dsr[mid] * self.inv_dt[None] / ti.sqrt(ti.max(pressure, 1.0e-12))
        I0 = self.I0[mid]
        B = I0 + k * (A * self.dmu[mid] - b)
        disc = ti.sqrt(B * B + 4.0 * k * b * I0)
        d = 0.0
        if B >= 0.0:
            d = 2.0 * b * I0 / (B + disc)
        else:
            d = (disc - B) / (2.0 * k)
        return ti.min(ti.max(d, 0.0), b)

    @ti.func
    def drucker_prager_return(self, ehat, norm, tr, tr_apex, bulk, mu, mid):
        """The cone's radial return (Klar et al. 2016, eq. 27) of the deviatoric Hencky strain ehat
        (norm |ehat|) at the volumetric strain tr < tr_apex: (new strains, whether it flowed)."""
        new_eps = ehat + tr / 3.0
        flowed = False
        dgamma = norm + bulk / (2.0 * mu) * self.alpha[mid] * (tr - tr_apex)  # Klar et al. eq. 27
        if ti.static(self.use_mu_i):
            if dgamma > 0.0 and self.dmu[mid] > 0.0:
                # cone slope alpha = sqrt(2) mu / 3 (simple_shear): |ehat| on the cone = A mu
                A = bulk / (2.0 * mu) * (tr_apex - tr) * ti.sqrt(2.0) / 3.0
                dgamma = self.mu_i_projection(mid, dgamma, A, bulk * (tr_apex - tr) / 3.0)
        if dgamma > 0.0:
            new_eps = ehat + tr / 3.0 - (dgamma / norm) * ehat
            flowed = True
        return new_eps, flowed

    @ti.func
    def mohr_coulomb_return(self, ehat, tr, tr_apex, bulk, mu, mid):
        """Exact return onto the Mohr-Coulomb pyramid of the deviatoric Hencky strain ehat at the
        volumetric strain tr < tr_apex: (new strains, whether it flowed).

        Principal Kirchhoff stresses sigma_i = 2 mu ehat_i + bulk tr / 3, sorted sigma_1 >= sigma_2 >=
        sigma_3 (tension positive); in strain units (divided by 2 mu) the planes are
        f_ij = (e_i - e_j) + (e_i + e_j + k) s <= 0, s = sin(phi_mc), k = bulk (tr - tr_apex) / (3 mu) < 0
        (the apex, cohesion / tan(friction_angle) as the cone's, is the mean stress at tr_apex). The flow
        potential is Tresca's sigma_1 - sigma_3 (zero dilatancy: the return keeps tr, as the cone's does):
        the plastic strain is dgamma_a (1, 0, -1) on the main plane f_13, plus dgamma_b (0, 1, -1) on the
        compression edge (sigma_1 = sigma_2: f_23 active too) or dgamma_c (1, -1, 0) on the extension edge
        (sigma_2 = sigma_3: f_12). Each return is linear in the dgammas, so exact: the main plane's
        dgamma_a = f_13 / 2, and the edges' 2 x 2 systems (de Souza Neto, Peric & Owen 2008, "Computational
        methods for plasticity", ch. 8, the Mohr-Coulomb return in principal stresses, with psi = 0). The
        main return is taken when it keeps the order; otherwise the edge on the side of the smaller
        principal gap. The apex (tr >= tr_apex) is the caller's, as for the cone: zero-dilatancy flow
        cannot reach it."""
        s = self.mc_sin[mid]
        k = bulk * (tr - tr_apex) / (3.0 * mu)
        # sort: i1 the largest (least compressive), i3 the smallest, i2 the other
        i1 = 0
        i3 = 0
        for i in ti.static(range(1, 3)):
            if ehat[i] > ehat[i1]:
                i1 = i
            if ehat[i] < ehat[i3]:
                i3 = i
        if i1 == i3:  # all equal: on the hydrostatic axis, inside (k < 0)
            i3 = (i1 + 2) % 3
        i2 = 3 - i1 - i3
        e1 = 0.0
        e2 = 0.0
        e3 = 0.0
        for i in ti.static(range(3)):
            if i == i1:
                e1 = ehat[i]
            if i == i2:
                e2 = ehat[i]
            if i == i3:
                e3 = ehat[i]
        f13 = (e1 - e3) + (e1 + e3 + k) * s
        d1 = 0.0  # plastic strain increments of the sorted principal strains
        d2 = 0.0
        d3 = 0.0
        flowed = False
        if f13 > 0.0:
            flowed = True
            ga = 0.5 * f13  # main plane
            if e1 - ga >= e2 and e3 + ga <= e2:
                d1 = ga
                d3 = -ga
            elif e1 - e2 <= e2 - e3:
                # compression edge (sigma_1 = sigma_2): f13 and f23 = (e2 - e3) + (e2 + e3 + k) s
                f23 = (e2 - e3) + (e2 + e3 + k) * s
                det = 4.0 - (1.0 - s) * (1.0 - s)
                ga = (2.0 * f13 - (1.0 - s) * f23) / det
                gb = (2.0 * f23 - (1.0 - s) * f13) / det
                d1 = ga
                d2 = gb
                d3 = -ga - gb
            else:
                # extension edge (sigma_2 = sigma_3): f13 and f12 = (e1 - e2) + (e1 + e2 + k) s
                f12 = (e1 - e2) + (e1 + e2 + k) * s
                det = 4.0 - (1.0 + s) * (1.0 + s)
                ga = (2.0 * f13 - (1.0 + s) * f12) / det
                gc = (2.0 * f12 - (1.0 + s) * f13) / det
                d1 = ga + gc
                d2 = -gc
                d3 = -ga
        new_eps = ehat + tr / 3.0
        for i in ti.static(range(3)):
            if i == i1:
                new_eps[i] -= d1
            if i == i2:
                new_eps[i] -= d2
            if i == i3:
                new_eps[i] -= d3
        return new_eps, flowed

    @ti.func
    def matsuoka_nakai_radius(self, mid, w):
        """The deviatoric radius u = |dev c| / p' of the Matsuoka-Nakai cone at the Lode parameter w.

        Principal stresses c_i = p' - u p' n_i (compression positive, from the apex; n the unit deviatoric
        direction of the tension-positive strains, w = n_1 n_2 n_3 in [-1, 1] / (3 sqrt 6), -: triaxial
        compression): I1 = 3 p', I2 = p'^2 (3 - u^2 / 2), I3 = p'^3 (1 - u^2 / 2 - w u^3), and
        I1 I2 - K I3 = 0 is the cubic h(u) = (9 - K) + (K - 3) / 2 u^2 + K w u^3 = 0 (Matsuoka & Nakai 1974).
        Its smallest positive root: h(0) = 9 - K < 0 and h rises on (0, u_m); for w >= 0 h is convex there
        and the root lies in (0, u_0], u_0 = sqrt(2 (K - 9) / (K - 3)) the root at w = 0 (the cone's); for
        w < 0 it lies in [u_0, u_m], u_m = (K - 3) / (3 K |w|) where h has its maximum (> 0: the cone lies
        inside the octant of compressions, so the ray from the axis meets it before I3 = 0). Newton from
        u_0, kept in the bracket by bisection; a handful of steps to round-off in f32 and f64 for K up to
        about 50 (friction_angle 40, cone simple_shear), at most 16 (near-double root as K grows)."""
        km9 = self.mn_km9[mid]
        B = self.mn_b[mid]
        C = self.mn_k[mid] * w
        u0 = ti.sqrt(km9 / B)
        lo = 0.0 * u0
        hi = u0
        if C < 0.0:
            lo = u0
            hi = 2.0 * B / (-3.0 * C)
        x = u0
        tol = ti.static(self.mn_tol)
        for _ in range(16):
            h = B * x * x + C * x * x * x - km9
            if h < 0.0:
                lo = x
            else:
                hi = x
            dh = 2.0 * B * x + 3.0 * C * x * x
            xn = 0.5 * (lo + hi)
            if dh > 0.0:
                xn = x - h / dh
                if xn < lo or xn > hi:
                    xn = 0.5 * (lo + hi)
            done = ti.abs(xn - x) <= tol * x
            x = xn
            if done:
                break
        return x

    @ti.func
    def matsuoka_nakai_return(self, ehat, norm, tr, tr_apex, bulk, mu, mid):
        """Return onto the Matsuoka-Nakai cone of the deviatoric Hencky strain ehat (norm |ehat|) at the
        volumetric strain tr < tr_apex: (new strains, whether it flowed).

        Principal Kirchhoff stresses from the apex, compression positive, in strain units (/ 2 mu):
        c_i = p' - ehat_i, p' = bulk (tr_apex - tr) / (6 mu) > 0. The flow is the cone's: zero dilatancy,
        along dev tau (the von Mises potential), so the return keeps tr and scales ehat at a fixed Lode
        angle, exact for Hencky elasticity because the flow direction is the same at the trial and the
        returned stress: ehat <- ehat u* p' / |ehat|, u* the cone's radius at that Lode angle
        (``matsuoka_nakai_radius``). Non-associated as the cone's and the pyramid's returns: the surface is
        Lode-dependent, the potential is not."""
        new_eps = ehat + tr / 3.0
        flowed = False
        pp = bulk * (tr_apex - tr) / (6.0 * mu)
        if norm > self.mn_inner[mid] * pp:  # inside the inscribed circle: elastic at every Lode angle
            n = ehat / norm
            w = ti.min(ti.max(n[0] * n[1] * n[2], -_MN_W_MAX), _MN_W_MAX)
            r = self.matsuoka_nakai_radius(mid, w) * pp
            if norm > r:
                new_eps = ehat * (r / norm) + tr / 3.0
                flowed = True
        return new_eps, flowed

    @ti.func
    def return_mapping(self, p, F, mid, mu, lam):
        U, s, V = self.decompose_warm(p, F)
        eps = self.log_strains(p, s, 1.0e-4)
        changed = False
        for i in ti.static(range(self.dim)):
            if s[i] <= 0.0:
                changed = True  # inverted: rebuilt from |s|
        vc = self.vc[p] * self.correct[mid]
        tr = eps.sum() + vc  # volumetric strain with the remembered separation volume
        ehat = eps - eps.sum() / 3.0
        norm = ehat.norm()
        bulk = 3.0 * lam + 2.0 * mu  # tr(tau) = bulk tr(eps)
        tr_apex = 3.0 * self.apex[mid] / bulk
        new_eps = eps
        vc_new = 0.0
        if tr >= tr_apex:
            # beyond the apex (grains separating): stress-free up to the cohesion, remember the volume
            new_eps = ti.Vector([tr_apex / 3.0] * 3)
            vc_new = tr - tr_apex
            changed = True
        else:
            corrected = ehat + tr / 3.0
            returned = corrected
            flowed = False
            if ti.static(self.use_mc and self.use_mn):
                if self.mc[mid] > 0.5:
                    returned, flowed = self.mohr_coulomb_return(ehat, tr, tr_apex, bulk, mu, mid)
                elif self.mn[mid] > 0.5:
                    returned, flowed = self.matsuoka_nakai_return(ehat, norm, tr, tr_apex, bulk, mu, mid)
                else:
                    returned, flowed = self.drucker_prager_return(ehat, norm, tr, tr_apex, bulk, mu, mid)
            elif ti.static(self.use_mc):
                if self.mc[mid] > 0.5:
                    returned, flowed = self.mohr_coulomb_return(ehat, tr, tr_apex, bulk, mu, mid)
                else:
                    returned, flowed = self.drucker_prager_return(ehat, norm, tr, tr_apex, bulk, mu, mid)
            elif ti.static(self.use_mn):
                if self.mn[mid] > 0.5:
                    returned, flowed = self.matsuoka_nakai_return(ehat, norm, tr, tr_apex, bulk, mu, mid)
                else:
                    returned, flowed = self.drucker_prager_return(ehat, norm, tr, tr_apex, bulk, mu, mid)
            else:
                returned, flowed = self.drucker_prager_return(ehat, norm, tr, tr_apex, bulk, mu, mid)
            if flowed:
                new_eps = returned
                changed = True
            elif vc != 0.0:
                new_eps = corrected
                changed = True
        self.vc[p] = vc_new
        # J_p J_E = J: the plastic volume ratio takes what the projection removed from J_E
        self.Jp[p] = self.Jp[p] * ti.exp(eps.sum() - new_eps.sum())
        Fn = F
        if changed:
            Fn = principal(U, ti.exp(self.in_plane(new_eps)), V)
        self.store_hencky(p, U, new_eps, mu, lam)
        return Fn

    @ti.func
    def tau_zz(self, p, F, J, mu, lam):
        return self.hencky_tau_zz(p, J, mu, lam)

    @ti.func
    def energy_density(self, p, F, J, mu, lam):
        return self.hencky_energy(p, F, mu, lam)
