"""MPM constitutive laws: the kernel half of the materials.

Each law is a small ``@ti.data_oriented`` class:

* ``key``: the name the solver files it under (:func:`law_key` maps a material config to it:
  ``corotation``, ``neohooken``, ``von_mises``, ``clamp``, ``sand``, ``snow``, ``liquid``,
  ``liquid_viscous``, ``muscle_corotation``, ``muscle_neohooken``);
* per-particle state it owns (the warm-start rotation of the corotated law, the plastic volume
  ratio ``Jp`` of snow, the volume correction of sand, muscle groups and fibres), allocated in
  :meth:`allocate` for the whole particle range and saved in restart files;
* per-material parameters beyond mu and lambda (yield stress, friction angle, hardening,
  viscosity) in fields indexed by material id (:meth:`allocate_materials`): run-time data;
* ``kirchhoff(p, F, J, mu, lam, update)``: Kirchhoff stress tau = P F^T = J sigma, the quantity
  MLS-MPM scatters (Hu et al. 2018, eq. 29 with tau instead of P F^T);
* ``return_mapping(p, F, mid, mu, lam)``: projection of the elastic deformation gradient after
  the update F <- (I + dt C) F. Elastic laws set ``plastic = False`` so the solver does not even
  compile the call. Laws whose return mapping needs an SVD (``stores_stress = True``) compute the
  Kirchhoff stress there, from the same singular values, and keep it per particle: the next
  p2g reads it instead of decomposing F again.

The plastic laws live in ``plasticity.py``, liquid and muscle in ``fluid_muscle.py``; the
registry ``LAWS`` in ``laws.py`` lists them all. The solver compiles in only the
laws of the materials present (``ti.static`` unrolling).
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
    return ti.Matrix(
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
            [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
            [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
        ]
    )


def identity_quaternions(n: int, dtype) -> np.ndarray:
    """(n, 4) unit quaternions (w, x, y, z) = (1, 0, 0, 0): the warm-start rotations' initial state."""
    q = np.zeros((n, 4), dtype)
    q[:, 0] = 1.0
    return q


@ti.func
def mat_to_quat(R):
    """Unit quaternion (w, x, y, z) of the rotation matrix R (Shepperd 1978: divide by the largest of
    4 w^2, 4 x^2, 4 y^2, 4 z^2, so no branch loses precision); normalised."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    q = ti.Vector([1.0, 0.0, 0.0, 0.0])
    if tr > 0.0:
        s = 2.0 * ti.sqrt(tr + 1.0)  # 4 w
        q = ti.Vector([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * ti.sqrt(ti.max(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 1.0e-12))  # 4 x
        q = ti.Vector([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * ti.sqrt(ti.max(1.0 + R[1, 1] - R[0, 0] - R[2, 2], 1.0e-12))  # 4 y
        q = ti.Vector([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * ti.sqrt(ti.max(1.0 + R[2, 2] - R[0, 0] - R[1, 1], 1.0e-12))  # 4 z
        q = ti.Vector([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    return q / q.norm()


@ti.func
def quat_mul(a, b):
    """Hamilton product a*b of quaternions (w, x, y, z)."""
    return ti.Vector(
        [
            a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
        ]
    )


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
            omega = (
                ti.Vector(
                    [
                        c00 * g[0] + c01 * g[1] + c02 * g[2],
                        c01 * g[0] + c11 * g[1] + c12 * g[2],
                        c02 * g[0] + c12 * g[1] + c22 * g[2],
                    ]
                )
                / det
            )
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
    stores_stress: ClassVar[bool] = False  # True when return_mapping computes and stores tau
    tracks_jp: ClassVar[bool] = False  # True when the law keeps the plastic volume ratio J_p
    hardens: ClassVar[bool] = False  # True when stiffness_factor can exceed 1 (stable_dt asks)

    def __init__(self, dim: int, dtype: Any, rotation_iters: int = 8) -> None:
        self.dim = dim
        self.dtype = dtype
        self.rotation_iters = rotation_iters
        # target error of the rotation extraction [rad]: a relative stress error of that order,
        # far below the strains an explicit MPM resolves; near the precision's resolution in f64
        self.rotation_tol = 1.0e-6 if dtype == ti.f32 else 1.0e-12
        self.n = 0
        self.n_materials = 0

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
        self.n_materials = len(materials)

    def bind(self, solver: Any) -> None:
        """Called once in build, after the solver's fields exist and the bodies are uploaded: a
        law that reads solver fields (the affine velocity C) or the bodies (muscle groups by
        region) takes what it needs here."""

    def host_update(self, t: float, dt: float) -> None:
        """Called by the solver before each substep with the time t [s] at its start (actuation) and
        the substep dt [s] (the mu(I) sand's shear rate)."""

    def max_wave_factor(self, materials: list) -> float:
        """Extra stiffness (x (lambda + 2 mu)) the law may add at most, for stable_dt (muscle)."""
        return 1.0

    # ---- kernel side
    @ti.func
    def return_mapping(self, p, F, mid, mu, lam):
        return F

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        return F * 0.0  # overridden by every law

    @ti.func
    def tau_zz(self, p, F, J, mu, lam):
        """Out-of-plane Kirchhoff stress of a 2D (plane strain, F_zz = 1) particle."""
        return 0.0

    @ti.func
    def energy_density(self, p, F, J, mu, lam):
        """Stored elastic energy per unit reference volume [J/m^3] of the elastic part F."""
        return 0.0

    @ti.func
    def plastic_J(self, p):
        """Plastic volume ratio J_p = J / J_E (1 where plastic flow keeps the volume)."""
        return 1.0

    @ti.func
    def elastic_J(self, p, J):
        """Elastic volume ratio J_E given J = det F (2D plane-strain plasticity adds F_zz^E)."""
        return J

    @ti.func
    def total_J(self, p, J):
        """Total volume ratio J = J_p J_E of the particle, given J = det F (F the elastic part)."""
        return self.elastic_J(p, J) * self.plastic_J(p)

    @ti.func
    def stiffness_factor(self, p):
        """Current stiffness over the initial one (snow hardening; 1 for the others)."""
        return 1.0

    def max_stiffness_factor(self, materials: list) -> float:
        """Largest stiffness factor the law can ever reach (stable_dt's cap)."""
        return 1.0


@ti.data_oriented
class CorotatedLaw(ConstitutiveLaw):
    """Fixed corotated elasticity (Stomakhin et al. 2012):
    tau = 2 mu (F - R) F^T + lambda (J - 1) J I, R the polar rotation of F;
    energy psi = mu |F - R|^2 + lambda / 2 (J - 1)^2.

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
            self.q.from_numpy(identity_quaternions(self.n, _np_dtype(self.dtype)))

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
        return 2.0 * mu * (F - R) @ F.transpose() + ti.Matrix.identity(self.dtype, self.dim) * (
            lam * (J - 1.0) * J
        )

    @ti.func
    def tau_zz(self, p, F, J, mu, lam):
        return lam * (J - 1.0) * J

    @ti.func
    def energy_density(self, p, F, J, mu, lam):
        R = self.rotation(p, F, False)
        return mu * ((F - R) * (F - R)).sum() + 0.5 * lam * (J - 1.0) ** 2


@ti.data_oriented
class NeoHookeanLaw(ConstitutiveLaw):
    """Compressible Neo-Hookean: tau = mu (F F^T - I) + lambda log(J) I;
    energy psi = mu / 2 (tr(F^T F) - d) - mu log J + lambda / 2 log(J)^2.

    J is floored at 1e-6 inside the logarithm so an inverted particle gives a huge restoring
    pressure instead of NaN (the frame check still reports the blow-up through the velocities).
    """

    key = "neohooken"

    @ti.func
    def kirchhoff(self, p, F, J, mu, lam, update: ti.template()):
        I = ti.Matrix.identity(self.dtype, self.dim)
        return mu * (F @ F.transpose() - I) + I * (lam * ti.log(ti.max(J, 1.0e-6)))

    @ti.func
    def tau_zz(self, p, F, J, mu, lam):
        return lam * ti.log(ti.max(J, 1.0e-6))

    @ti.func
    def energy_density(self, p, F, J, mu, lam):
        lj = ti.log(ti.max(J, 1.0e-6))
        return 0.5 * mu * ((F * F).sum() - self.dim) - mu * lj + 0.5 * lam * lj * lj


def elastic_moduli(material: Any) -> tuple[float, float]:
    """(mu, lambda) [Pa] the solver keeps per material: the elastic Lame parameters (a liquid has
    no shear modulus; its viscosity is a parameter of the liquid law)."""
    if getattr(material, "type", "") == "MPM.Liquid":
        return 0.0, float(material.lam)
    return float(material.mu), float(material.lam)


def law_key(material: Any) -> str:
    """The law a material config asks for."""
    mtype = getattr(material, "type", "")
    if mtype == "MPM.Elastic":
        return material.model
    if mtype == "MPM.ElastoPlastic":
        return "von_mises" if material.use_von_mises else "clamp"
    if mtype == "MPM.Sand":
        return "sand"
    if mtype == "MPM.Snow":
        return "snow"
    if mtype == "MPM.Liquid":
        return "liquid_viscous" if material.viscous else "liquid"
    if mtype == "MPM.Muscle":
        return "muscle_" + material.model
    raise ValueError(f"material type {mtype!r} is not an MPM material implemented by this solver")


def _np_dtype(dtype: Any):
    return np.float64 if dtype == ti.f64 else np.float32
