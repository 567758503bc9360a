"""Constitutive models of linear tetrahedra: energy density psi(F), first Piola-Kirchhoff stress
P = dpsi/dF and the stress derivative dP/dF, as Taichi funcs.

dP/dF is never stored as a 9x9 matrix. Every model gives it in the "singular-value frame" of
Teran et al. 2005 / Smith et al. 2018: with F = U diag(s) V^T (signed, U and V rotations),

* ``Hs`` (3x3): d^2 psi / ds_i ds_j, acting on the diagonal of dF' = U^T dF V;
* for each pair (i, j) (order (0,1), (1,2), (0,2)), on (dF'_ij, dF'_ji), the 2x2 block with
  eigenvalue ``ls`` on (1, 1) ("flip", (psi_i - psi_j)/(s_i - s_j)) and ``lt`` on (1, -1)
  ("twist", (psi_i + psi_j)/(s_i + s_j)),

and dP = U dP' V^T. Projecting dP/dF to positive semi-definite is clamping the eigenvalues of Hs
and ls, lt at zero. The linear model fits the same form with U = V = I (Hs = 2 mu I + lambda 1 1^T,
ls = 2 mu, lt = 0).

Models (mu, lam are the Lame parameters passed at run time):

* ``linear``: psi = mu eps:eps + lam/2 tr(eps)^2, eps = sym(F) - I. Not rotation invariant.
* ``linear_corotated``: psi = mu |S - I|^2 + lam/2 tr(S - I)^2 with F = R S (polar, R a rotation;
  inversion-aware through the signed SVD).
* ``stable_neohookean`` (Smith, de Goes and Kim 2018, the form without the log term, as in their
  HOBAK code): psi = mu/2 (I_C - 3) - mu (J - 1) + lam'/2 (J - 1)^2 with lam' = lam + mu, so that it
  linearises to 2 mu eps + lam tr(eps) I at rest (Smith et al. sec. 3.4: the Lame reparameterisation);
  the solver passes lam' (see ``lame_for``).
* ``neohookean``: the classical compressible neo-Hookean model (Bonet and Wood, Nonlinear Continuum
  Mechanics for Finite Element Analysis, 2nd ed. 2008, eq. 6.28): psi = mu/2 (I_C - 3) - mu ln J +
  lam/2 (ln J)^2, P = mu (F - F^-T) + lam ln J F^-T; it linearises to Hooke's law with the Lame
  parameters as given. ln J is undefined for J <= 0: below J = ``NH_J_MIN`` (0.01) ln J is replaced by its
  second-order Taylor expansion about NH_J_MIN (the inversion guard), so energy, stress and Hessian stay
  finite and twice continuously differentiable for every F, inverted ones included, and an element
  squashed past 1 % of its volume feels a pressure that keeps growing as J falls (it is pushed back, no
  NaN). Only elements below J = 0.01 see the extension; above it the model is exact.
* ``neohookean_decoupled``: the decoupled compressible neo-Hookean of the deal.II code gallery's Cook
  membrane (Pelteret and McBride 2016, doi:10.5281/zenodo.1228964; the model of step-44 without its three
  fields): psi = mu/2 (J^(-2/3) I_C - 3) + kappa/4 (J^2 - 1 - 2 ln J), kappa = lam + 2 mu / 3 (the solver
  passes kappa). It linearises to Hooke's law like the others; J^(-2/3) and ln J carry the same inversion
  guard below J = 0.01.
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.taichi_funcs import jacobi_rotation

with stdout_to_stderr():
    import taichi as ti

MODELS = ("linear", "linear_corotated", "stable_neohookean", "neohookean", "neohookean_decoupled")
NH_J_MIN = 0.01  # neohookean: below this J, ln J is continued by its second-order Taylor polynomial
TWIST_EPS = 1e-6  # |s_i + s_j| below this: the twist eigenvalue's denominator is clamped


def lame_for(model: str, mu: float, lam: float) -> tuple[float, float]:
    """The (mu, lambda) a model's kernel gets for a material with Lame parameters (mu, lam)."""
    if model == "stable_neohookean":
        return mu, lam + mu
    if model == "neohookean_decoupled":  # its second parameter is the bulk modulus kappa
        return mu, lam + 2.0 * mu / 3.0
    return mu, lam


@ti.func
def cofactor(F):
    """cof(F) = dJ/dF = J F^-T, from cross products of F's columns (defined for any F)."""
    c0 = ti.Vector([F[0, 1], F[1, 1], F[2, 1]]).cross(ti.Vector([F[0, 2], F[1, 2], F[2, 2]]))
    c1 = ti.Vector([F[0, 2], F[1, 2], F[2, 2]]).cross(ti.Vector([F[0, 0], F[1, 0], F[2, 0]]))
    c2 = ti.Vector([F[0, 0], F[1, 0], F[2, 0]]).cross(ti.Vector([F[0, 1], F[1, 1], F[2, 1]]))
    return ti.Matrix.cols([c0, c1, c2])


@ti.func
def signed_svd(F):
    """F = U diag(s) V^T with U, V proper rotations; an inverted F gets a negative s[2]."""
    U, S, V = ti.svd(F)
    if U.determinant() < 0:
        for i in ti.static(range(3)):
            U[i, 2] = -U[i, 2]
        S[2, 2] = -S[2, 2]
    if V.determinant() < 0:
        for i in ti.static(range(3)):
            V[i, 2] = -V[i, 2]
        S[2, 2] = -S[2, 2]
    return U, ti.Vector([S[0, 0], S[1, 1], S[2, 2]]), V


@ti.func
def _project_sym3(H):
    """Clamp the eigenvalues of a symmetric 3x3 matrix at zero. A positive definite H (Sylvester's
    criterion) is returned as it is: the eigen-solver is only used when needed (it is also the least
    accurate step when eigenvalues repeat, as at rest)."""
    m1 = H[0, 0]
    m2 = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
    r = H
    if not (m1 > 0 and m2 > 0 and H.determinant() > 0):
        A, Q = _jacobi_eig3(H)
        r = (
            Q
            @ ti.Matrix(
                [
                    [ti.max(A[0, 0], 0.0), 0.0, 0.0],
                    [0.0, ti.max(A[1, 1], 0.0), 0.0],
                    [0.0, 0.0, ti.max(A[2, 2], 0.0)],
                ]
            )
            @ Q.transpose()
        )
    return r


@ti.func
def _jacobi_sweep(A, Q):
    """One cyclic Jacobi sweep (rotations (0,1), (0,2), (1,2)) on A, accumulated into Q."""
    for pq in ti.static([(0, 1), (0, 2), (1, 2)]):
        p, q = ti.static(pq[0], pq[1])
        apq = A[p, q]
        if ti.abs(apq) > 1e-30:
            _, c, sn = jacobi_rotation(A[p, p], A[q, q], apq)
            J = ti.Matrix.identity(float, 3)
            J[p, p] = c
            J[q, q] = c
            J[p, q] = sn
            J[q, p] = -sn
            A = J.transpose() @ A @ J
            Q = Q @ J
    return A, Q


@ti.func
def _jacobi_eig3(H):
    """Cyclic Jacobi eigen-decomposition of a symmetric 3x3 matrix: H = Q diag(A) Q^T (6 sweeps).
    Used instead of ti.sym_eig, which returned eigenvalues off by orders of magnitude in f32 for the
    rank-deficient matrices of inverted elements.

    Sweeps 2-6 are a run-time loop: all six unrolled (ti.static), this function alone took ~25 s of
    compilation on a cold kernel cache, most of the stable Neo-Hookean implicit ``hessian`` kernel's
    ~48 s (the 51 s ``build_s`` seen on CUDA, whose machine starts with an empty cache). The first sweep
    stays inlined: the compiler fuses its arithmetic with the expressions of H (fast math), so rolling
    it too would change results in the last bits."""
    A, Q = _jacobi_sweep(H, ti.Matrix.identity(float, 3))
    for _sweep in range(5):
        A, Q = _jacobi_sweep(A, Q)
    return A, Q


@ti.func
def apply_dP(U, V, Hs, ls, lt, dF):
    """dP = (dP/dF) : dF in the singular-value frame form (see the module docstring)."""
    d = U.transpose() @ dF @ V
    r = ti.Matrix.zero(float, 3, 3)
    for i in ti.static(range(3)):
        acc = 0.0 * d[0, 0]
        for j in ti.static(range(3)):
            acc += Hs[i, j] * d[j, j]
        r[i, i] = acc
    for k in ti.static(range(3)):
        i, j = ti.static([(0, 1), (1, 2), (0, 2)][k])
        a = 0.5 * (ls[k] + lt[k])
        b = 0.5 * (ls[k] - lt[k])
        r[i, j] = a * d[i, j] + b * d[j, i]
        r[j, i] = b * d[i, j] + a * d[j, i]
    return U @ r @ V.transpose()


@ti.func
def _twist(gi, gj, si, sj):
    den = si + sj
    if ti.abs(den) < TWIST_EPS:
        den = TWIST_EPS if den >= 0 else -TWIST_EPS
    return (gi + gj) / den


class Linear:
    name = "linear"

    @staticmethod
    @ti.func
    def energy(F, mu, lam):
        eps = 0.5 * (F + F.transpose()) - ti.Matrix.identity(float, 3)
        tr = eps.trace()
        return mu * (eps * eps).sum() + 0.5 * lam * tr * tr

    @staticmethod
    @ti.func
    def pk1(F, mu, lam):
        eps = 0.5 * (F + F.transpose()) - ti.Matrix.identity(float, 3)
        return 2.0 * mu * eps + lam * eps.trace() * ti.Matrix.identity(float, 3)

    @staticmethod
    @ti.func
    def hessian(F, mu, lam, project: ti.template()):
        Id = ti.Matrix.identity(float, 3)
        Hs = 2.0 * mu * Id + lam * ti.Matrix([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], float)
        ls = ti.Vector([2.0 * mu, 2.0 * mu, 2.0 * mu], float)
        lt = ti.Vector.zero(float, 3)
        return Id, Id, Hs, ls, lt


class LinearCorotated:
    name = "linear_corotated"

    @staticmethod
    @ti.func
    def energy(F, mu, lam):
        U, s, V = signed_svd(F)
        e = s - 1.0
        tr = e.sum()
        return mu * e.dot(e) + 0.5 * lam * tr * tr

    @staticmethod
    @ti.func
    def pk1(F, mu, lam):
        U, s, V = signed_svd(F)
        R = U @ V.transpose()
        tr = s.sum() - 3.0
        return 2.0 * mu * (F - R) + lam * tr * R

    @staticmethod
    @ti.func
    def hessian(F, mu, lam, project: ti.template()):
        U, s, V = signed_svd(F)
        tr = s.sum() - 3.0
        g = 2.0 * mu * (s - 1.0) + lam * tr
        Hs = 2.0 * mu * ti.Matrix.identity(float, 3) + lam * ti.Matrix(
            [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], float
        )
        ls = ti.Vector([2.0 * mu, 2.0 * mu, 2.0 * mu], float)
        lt = ti.Vector(
            [_twist(g[0], g[1], s[0], s[1]), _twist(g[1], g[2], s[1], s[2]), _twist(g[0], g[2], s[0], s[2])],
            float,
        )
        if ti.static(project):  # Hs = 2 mu I + lam 1 1^T is positive definite (bulk modulus > 0)
            ls = ti.max(ls, 0.0)
            lt = ti.max(lt, 0.0)
        return U, V, Hs, ls, lt


class StableNeoHookean:
    name = "stable_neohookean"

    @staticmethod
    @ti.func
    def energy(F, mu, lam):
        J = F.determinant()
        return 0.5 * mu * ((F * F).sum() - 3.0) - mu * (J - 1.0) + 0.5 * lam * (J - 1.0) * (J - 1.0)

    @staticmethod
    @ti.func
    def pk1(F, mu, lam):
        J = F.determinant()
        return mu * F + (lam * (J - 1.0) - mu) * cofactor(F)

    @staticmethod
    @ti.func
    def hessian(F, mu, lam, project: ti.template()):
        U, s, V = signed_svd(F)
        J = s[0] * s[1] * s[2]
        c = lam * (J - 1.0) - mu
        o = ti.Vector([s[1] * s[2], s[0] * s[2], s[0] * s[1]])  # J / s_i
        Hs = ti.Matrix.zero(float, 3, 3)
        for i in ti.static(range(3)):
            for j in ti.static(range(3)):
                if ti.static(i == j):
                    Hs[i, j] = mu + lam * o[i] * o[i]
                else:
                    k = ti.static(3 - i - j)
                    Hs[i, j] = s[k] * (lam * (2.0 * J - 1.0) - mu)
        # pairs (0,1), (1,2), (0,2): the third index 2, 0, 1
        sk = ti.Vector([s[2], s[0], s[1]])
        ls = mu - c * sk
        lt = mu + c * sk
        if ti.static(project):
            Hs = _project_sym3(Hs)
            ls = ti.max(ls, 0.0)
            lt = ti.max(lt, 0.0)
        return U, V, Hs, ls, lt


@ti.func
def _guarded_log(J):
    """(f, f', f'') with f = ln J for J >= NH_J_MIN and its second-order Taylor polynomial about NH_J_MIN
    below (defined for J <= 0: the neohookean inversion guard)."""
    f = 0.0 * J
    d1 = 0.0 * J
    d2 = 0.0 * J
    if J >= NH_J_MIN:
        f = ti.log(J)
        d1 = 1.0 / J
        d2 = -1.0 / (J * J)
    else:
        a = J - NH_J_MIN
        f = ti.log(NH_J_MIN) + a / NH_J_MIN - 0.5 * a * a / (NH_J_MIN * NH_J_MIN)
        d1 = 1.0 / NH_J_MIN - a / (NH_J_MIN * NH_J_MIN)
        d2 = -1.0 / (NH_J_MIN * NH_J_MIN) + 0.0 * J
    return f, d1, d2


class NeoHookean:
    """Classical compressible neo-Hookean (Bonet and Wood 2008, eq. 6.28), with the inversion guard of
    ``_guarded_log``. In the singular values: psi = mu/2 (sum s_i^2 - 3) + h(J), h = -mu f + lam/2 f^2,
    so dpsi/ds_i = mu s_i + h' J / s_i and the flip/twist eigenvalues are mu -/+ h' s_k (as for
    stable_neohookean with its h)."""

    name = "neohookean"

    @staticmethod
    @ti.func
    def energy(F, mu, lam):
        lj, d1, d2 = _guarded_log(F.determinant())
        return 0.5 * mu * ((F * F).sum() - 3.0) - mu * lj + 0.5 * lam * lj * lj

    @staticmethod
    @ti.func
    def pk1(F, mu, lam):
        lj, d1, d2 = _guarded_log(F.determinant())
        return mu * F + (lam * lj - mu) * d1 * cofactor(F)

    @staticmethod
    @ti.func
    def hessian(F, mu, lam, project: ti.template()):
        U, s, V = signed_svd(F)
        J = s[0] * s[1] * s[2]
        lj, d1, d2 = _guarded_log(J)
        h1 = (lam * lj - mu) * d1  # h'(J)
        h2 = lam * d1 * d1 + (lam * lj - mu) * d2  # h''(J)
        o = ti.Vector([s[1] * s[2], s[0] * s[2], s[0] * s[1]])  # J / s_i
        Hs = ti.Matrix.zero(float, 3, 3)
        for i in ti.static(range(3)):
            for j in ti.static(range(3)):
                if ti.static(i == j):
                    Hs[i, j] = mu + h2 * o[i] * o[i]
                else:
                    k = ti.static(3 - i - j)
                    Hs[i, j] = h2 * o[i] * o[j] + h1 * s[k]
        sk = ti.Vector([s[2], s[0], s[1]])  # pairs (0,1), (1,2), (0,2): the third index 2, 0, 1
        ls = mu - h1 * sk
        lt = mu + h1 * sk
        if ti.static(project):
            Hs = _project_sym3(Hs)
            ls = ti.max(ls, 0.0)
            lt = ti.max(lt, 0.0)
        return U, V, Hs, ls, lt


# neohookean_decoupled: J^(-2/3) and its first two derivatives at NH_J_MIN (the guard's Taylor polynomial)
_G0 = NH_J_MIN ** (-2.0 / 3.0)
_G1 = -2.0 / 3.0 * _G0 / NH_J_MIN
_G2 = 10.0 / 9.0 * _G0 / (NH_J_MIN * NH_J_MIN)


@ti.func
def _guarded_pow(J):
    """(g, g', g'') with g = J^(-2/3) for J >= NH_J_MIN and its second-order Taylor polynomial about NH_J_MIN
    below (defined for J <= 0, decreasing: the inversion guard of neohookean_decoupled, like _guarded_log)."""
    g = 0.0 * J
    d1 = 0.0 * J
    d2 = 0.0 * J
    if J >= NH_J_MIN:
        g = ti.pow(J, -2.0 / 3.0)
        d1 = -2.0 / 3.0 * g / J
        d2 = 10.0 / 9.0 * g / (J * J)
    else:
        a = J - NH_J_MIN
        g = _G0 + _G1 * a + 0.5 * _G2 * a * a
        d1 = _G1 + _G2 * a
        d2 = _G2 + 0.0 * J
    return g, d1, d2


class NeoHookeanDecoupled:
    """The decoupled compressible neo-Hookean of the deal.II code gallery's Cook membrane (Pelteret and
    McBride 2016, the model of step-44 without its three fields; Miehe 1994): psi = mu/2 (J^(-2/3) I_C - 3) +
    kappa/4 (J^2 - 1 - 2 ln J), kappa = lam + 2 mu / 3 the bulk modulus (the solver passes kappa, see
    ``lame_for``). J^(-2/3) and ln J carry the inversion guard below J = NH_J_MIN. In the singular values:
    psi = mu/2 (g(J) sum s_i^2 - 3) + h(J), dpsi/ds_i = mu g s_i + c J / s_i with c = mu/2 g' I_C + h'; the
    flip/twist eigenvalues are mu g -/+ c s_k."""

    name = "neohookean_decoupled"

    @staticmethod
    @ti.func
    def energy(F, mu, lam):
        J = F.determinant()
        g, g1, g2 = _guarded_pow(J)
        lj, l1, l2 = _guarded_log(J)
        return 0.5 * mu * (g * (F * F).sum() - 3.0) + 0.25 * lam * (J * J - 1.0 - 2.0 * lj)

    @staticmethod
    @ti.func
    def pk1(F, mu, lam):
        J = F.determinant()
        g, g1, g2 = _guarded_pow(J)
        lj, l1, l2 = _guarded_log(J)
        c = 0.5 * mu * g1 * (F * F).sum() + 0.5 * lam * (J - l1)
        return mu * g * F + c * cofactor(F)

    @staticmethod
    @ti.func
    def hessian(F, mu, lam, project: ti.template()):
        U, s, V = signed_svd(F)
        J = s[0] * s[1] * s[2]
        g, g1, g2 = _guarded_pow(J)
        lj, l1, l2 = _guarded_log(J)
        I1 = s.dot(s)
        h1 = 0.5 * lam * (J - l1)  # h'(J), h = lam/4 (J^2 - 1 - 2 ln J)
        h2 = 0.5 * lam * (1.0 - l2)  # h''(J)
        c = 0.5 * mu * g1 * I1 + h1
        o = ti.Vector([s[1] * s[2], s[0] * s[2], s[0] * s[1]])  # J / s_i
        Hs = ti.Matrix.zero(float, 3, 3)
        for i in ti.static(range(3)):
            for j in ti.static(range(3)):
                dc = 0.5 * mu * (g2 * o[j] * I1 + 2.0 * g1 * s[j]) + h2 * o[j]  # dc / ds_j
                v = mu * g1 * o[j] * s[i] + dc * o[i]
                if ti.static(i == j):
                    v += mu * g
                else:
                    v += c * s[ti.static(3 - i - j)]
                Hs[i, j] = v
        sk = ti.Vector([s[2], s[0], s[1]])  # pairs (0,1), (1,2), (0,2): the third index 2, 0, 1
        ls = mu * g - c * sk
        lt = mu * g + c * sk
        if ti.static(project):
            Hs = _project_sym3(Hs)
            ls = ti.max(ls, 0.0)
            lt = ti.max(lt, 0.0)
        return U, V, Hs, ls, lt


LAWS = {
    "linear": Linear,
    "linear_corotated": LinearCorotated,
    "stable_neohookean": StableNeoHookean,
    "neohookean": NeoHookean,
    "neohookean_decoupled": NeoHookeanDecoupled,
}
