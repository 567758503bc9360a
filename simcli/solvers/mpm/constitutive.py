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
    """Rotational part of a 3x3 matrix A by Mueller et al. 2016, "A Robust Method to Extract the
    Rotational Part of Deformations" (MIG '16), warm-started from the quaternion ``q``.

    Each iteration rotates R = R(q) by the angle-axis ``omega = sum_i r_i x a_i / |sum_i r_i . a_i|``
    (r_i, a_i the columns of R and A), which drives R towards the maximiser of tr(R^T A) over
    SO(3): the rotation of the polar decomposition A = R S when det A > 0, and the same
    "rotation-variant" R = U diag(1, 1, det(U V^T)) V^T as an SVD-based polar when det A <= 0.
    Warm-started from the previous substep's rotation it needs one or two iterations at small
    strains; each iteration shrinks the error by about (s_max - s_min)/(s_max + s_min) of the
    stretch, so large anisotropic stretches need more (the solver allows up to
    ``rotation_iters`` per substep and stops at ``tol``).
    Returns the new unit quaternion.
    """
    for _ in range(max_iter):
        R = quat_to_mat(q)
        num = ti.Vector([0.0, 0.0, 0.0])
        den = 0.0
        for i in ti.static(range(3)):
            r = ti.Vector([R[0, i], R[1, i], R[2, i]])
            a = ti.Vector([A[0, i], A[1, i], A[2, i]])
            num += r.cross(a)
            den += r.dot(a)
        omega = num / (ti.abs(den) + 1.0e-9)
        w = omega.norm()
        if w < tol:
            break
        half = 0.5 * w
        s = ti.sin(half) / w
        dq = ti.Vector([ti.cos(half), s * omega[0], s * omega[1], s * omega[2]])
        q = quat_mul(dq, q)
        q = q / q.norm()
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
        # convergence threshold of the rotation extraction [rad]: about the precision's resolution
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
