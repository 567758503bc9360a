"""MPM constitutive laws: the kernel half of the materials.

Each law is a small ``@ti.data_oriented`` class:

* ``key``: the name the scene uses for it (``MPMElastic.model``; later e.g. ``"sand"``);
* per-particle state it owns (e.g. the warm-start rotation of the corotated law, later the
  plastic ``Jp`` of snow or the hardening state of Drucker-Prager sand), allocated in
  :meth:`allocate` for the whole particle range and saved in restart files;
* ``kirchhoff(p, F, J, mu, lam, update)``: Kirchhoff stress tau = P F^T = J sigma, the quantity
  MLS-MPM scatters (Hu et al. 2018, eq. 29 with tau instead of P F^T);
* ``return_mapping(p, F, mid)``: projection of the elastic deformation gradient after the
  update F <- (I + dt C) F. Elastic laws return F unchanged and set ``plastic = False`` so the
  solver does not even compile the call; plastic laws (von Mises clamp, Drucker-Prager,
  snow hardening) implement it with their own state.

Numbers (mu, lambda, later yield stress...) are run-time data indexed by material id; the
solver compiles in only the laws of the materials present (``ti.static`` unrolling).
"""


from typing import Any, ClassVar

import numpy as np

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti


# ------------------------------------------------------------- rotation extraction


@ti.func
def quat_to_mat(q):
    """Rotation matrix of the unit quaternion q = (w, x, y, z)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ti.Matrix([
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ])


@ti.func
def quat_mul(a, b):
    """Hamilton product a*b of quaternions (w, x, y, z)."""
    return ti.Vector([
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ])


@ti.func
def extract_rotation(A, q, max_iter: ti.template(), tol):
    """Rotational part of a 3x3 matrix A, warm-started from the unit quaternion ``q = (w, x, y, z)``.

    The iteration of Mueller et al. 2016, "A Robust Method to Extract the Rotational Part of
    Deformations" (MIG '16), with a Newton step: R = R(q) is rotated by exp(omega), where
    g = sum_i r_i x a_i = axial(M - M^T), M = A R^T, is the gradient of tr(R^T A) and
    H = tr(M) I - sym(M) its Hessian. Mueller's step omega = g / |tr M| only corrects about
    2/3 of the error per iteration (1/3 left even for a pure rotation, so 6 iterations per
    decade of accuracy); the Newton step omega = H^-1 g converges quadratically, typically in one
    or two iterations from the previous substep's rotation. Where H is not positive definite
    (far from the optimum, inverted elements) Mueller's step is used, which always ascends.

    The maximiser of tr(R^T A) over SO(3) is the rotation of the polar decomposition A = R S
    when det A > 0, and the same "rotation-variant" R = U diag(1, 1, det(U V^T)) V^T as an
    SVD-based polar when det A <= 0. Stops when the rotation error is estimated below ``tol``
    [rad]: |omega| < tol before a step, or |omega|^2 < tol after a Newton step (quadratic
    convergence; this saves the second evaluation in most substeps), or after ``max_iter``
    iterations. Returns the new unit quaternion.
    """
    for _ in range(max_iter):
        R = quat_to_mat(q)
        M = A @ R.transpose()
        g = ti.Vector([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
        tr = M[0, 0] + M[1, 1] + M[2, 2]
        # H = tr I - sym(M), symmetric: entries h00.. h12
        h00 = tr - M[0, 0]
        h11 = tr - M[1, 1]
        h22 = tr - M[2, 2]
        h01 = -0.5 * (M[0, 1] + M[1, 0])
        h02 = -0.5 * (M[0, 2] + M[2, 0])
        h12 = -0.5 * (M[1, 2] + M[2, 1])
        # adjugate and determinant for the 3x3 solve
        c00 = h11 * h22 - h12 * h12
        c01 = h02 * h12 - h01 * h22
        c02 = h01 * h12 - h02 * h11
        det = h00 * c00 + h01 * c01 + h02 * c02
        omega = g / (ti.abs(tr) + 1.0e-9)  # Mueller's step
        newton = False
        # Sylvester's criterion: H positive definite, and not nearly singular
        if h00 > 0 and h00 * h11 - h01 * h01 > 0 and det > 1.0e-6 * h00 * h00 * h00:
            newton = True
            c11 = h00 * h22 - h02 * h02
            c12 = h01 * h02 - h00 * h12
            c22 = h00 * h11 - h01 * h01
            omega = ti.Vector([
                c00 * g[0] + c01 * g[1] + c02 * g[2],
                c01 * g[0] + c11 * g[1] + c12 * g[2],
                c02 * g[0] + c12 * g[1] + c22 * g[2],
            ]) / det
        w = omega.norm()
        if w < tol:
            break
        # q <- exp(omega) q; for small angles the first-order quaternion (1, omega/2), normalised,
        # rotates by 2 atan(w/2) = w - w^3/12: enough for an iteration, and no sin/cos
        dq = ti.Vector([1.0, 0.5 * omega[0], 0.5 * omega[1], 0.5 * omega[2]])
        if w > 0.25:
            half = 0.5 * w
            s = ti.sin(half) / w
            dq = ti.Vector([ti.cos(half), s * omega[0], s * omega[1], s * omega[2]])
        q = quat_mul(dq, q)
        q = q / q.norm()
        if newton and w * w < tol:
            break
    return q


@ti.func
def polar_rotation_2d(F):
    """Closed-form rotation maximising tr(R^T F) for a 2x2 F (the polar rotation when det F > 0)."""
    a = F[0, 0] + F[1, 1]
    b = F[1, 0] - F[0, 1]
    r = ti.sqrt(a * a + b * b)
    c = 1.0
    s = 0.0
    if r > 0:
        c = a / r
        s = b / r
    return ti.Matrix([[c, -s], [s, c]])


# ------------------------------------------------------------------------- laws


@ti.data_oriented
class ConstitutiveLaw:
    """Base class; see the module docstring for the contract."""

    key: ClassVar[str] = ""
    plastic: ClassVar[bool] = False  # True when return_mapping changes F

    def __init__(self, dim: int, dtype: Any, rotation_iters: int = 8) -> None:
        self.dim = dim
        self.dtype = dtype
        self.rotation_iters = rotation_iters
        # target error of the rotation extraction [rad]: a relative stress error of that order,
        # far below the strains an explicit MPM resolves; near the precision's resolution in f64
        self.rotation_tol = 1.0e-6 if dtype == ti.f32 else 1.0e-12
        self.n = 0

    # ---- per-particle state (host side)
    def allocate(self, n: int) -> None:
        self.n = n

    def state_names(self) -> list[str]:
        return []

    def init_state(self) -> None:
        """Initial state for all particles (undeformed)."""

    def get_state(self) -> dict[str, np.ndarray]:
        return {}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        pass

    # ---- per-material parameters beyond mu and lambda (host side)
    def allocate_materials(self, materials: list) -> None:
        """Called once in build with every material config of the solver, indexed by material id.
        A law with parameters of its own (yield stress, friction angle, hardening...) allocates a
        field per parameter here and fills the entries of the materials that use it; its funcs
        index them with the ``mid`` they receive. Elastic laws need nothing beyond mu, lambda."""

    # ---- kernel side
    @ti.func
    def return_mapping(self, p, F, mid):
        return F

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        return F * 0.0  # overridden by every law

    @ti.func
    def tau_zz(self, F, J, mu, lam):
        """Out-of-plane Kirchhoff stress of a 2D (plane strain, F_zz = 1) particle."""
        return 0.0


@ti.data_oriented
class CorotatedLaw(ConstitutiveLaw):
    """Fixed corotated elasticity (Stomakhin et al. 2012):
    tau = 2 mu (F - R) F^T + lambda (J - 1) J I, R the polar rotation of F.

    3D: R by the warm-started rotation extraction of Mueller et al. 2016; the quaternion of each
    particle is state (``corotation_q``) so a restart continues bit-for-bit. 2D: closed form.
    """

    key = "corotation"

    def allocate(self, n: int) -> None:
        self.n = n
        self.q = ti.Vector.field(4, self.dtype, shape=n) if self.dim == 3 else None

    def state_names(self) -> list[str]:
        return ["corotation_q"] if self.dim == 3 else []

    def init_state(self) -> None:
        if self.q is not None:
            q = np.zeros((self.n, 4), dtype=np.float64)
            q[:, 0] = 1.0
            self.q.from_numpy(q.astype(_np_dtype(self.dtype)))

    def get_state(self) -> dict[str, np.ndarray]:
        return {"corotation_q": self.q.to_numpy()} if self.q is not None else {}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        if self.q is not None:
            self.q.from_numpy(np.ascontiguousarray(state["corotation_q"], dtype=_np_dtype(self.dtype)))

    @ti.func
    def rotation(self, p, F, update: ti.template()):
        R = ti.Matrix.identity(self.dtype, self.dim)
        if ti.static(self.dim == 3):
            if ti.static(update):
                q = extract_rotation(F, self.q[p], self.rotation_iters, self.rotation_tol)
                self.q[p] = q
                R = quat_to_mat(q)
            else:
                # outputs: converge further from the stored rotation, leave the state alone
                R = quat_to_mat(extract_rotation(F, self.q[p], 32, self.rotation_tol))
        else:
            R = polar_rotation_2d(F)
        return R

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        R = self.rotation(p, F, update)
        return 2.0 * mu * (F - R) @ F.transpose() + ti.Matrix.identity(self.dtype, self.dim) * (lam * (J - 1.0) * J)

    @ti.func
    def tau_zz(self, F, J, mu, lam):
        return lam * (J - 1.0) * J


@ti.data_oriented
class NeoHookeanLaw(ConstitutiveLaw):
    """Compressible Neo-Hookean: tau = mu (F F^T - I) + lambda log(J) I.

    J is floored at 1e-6 inside the logarithm so an inverted particle gives a huge restoring
    pressure instead of NaN (the frame check still reports the blow-up through the velocities).
    """

    key = "neohooken"

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        I = ti.Matrix.identity(self.dtype, self.dim)
        return mu * (F @ F.transpose() - I) + I * (lam * ti.log(ti.max(J, 1.0e-6)))

    @ti.func
    def tau_zz(self, F, J, mu, lam):
        return lam * ti.log(ti.max(J, 1.0e-6))


# Registry: material model name -> law. Add new laws here (and their config in scene/materials.py).
LAWS: dict[str, type[ConstitutiveLaw]] = {law.key: law for law in (CorotatedLaw, NeoHookeanLaw)}


def law_key(material: Any) -> str:
    """The law a material config asks for."""
    mtype = getattr(material, "type", "")
    if mtype == "MPM.Elastic":
        return material.model
    raise ValueError(f"material type {mtype!r} is not an MPM material implemented by this solver")


def _np_dtype(dtype: Any):
    return np.float64 if dtype == ti.f64 else np.float32
