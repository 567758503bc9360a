"""Free rigid bodies as unknowns of FEM.Cloth's Newton system (the IPC way for rigid bodies, a reduced form of
Ferguson et al. 2021, "Intersection-free rigid body dynamics": the body's triangles are a rigid map of its
6 degrees of freedom inside the one incremental potential).

Per body k and substep [t, t + dt], from its state at t (simcli.rigid: centre of mass c_n, rotation R_n,
velocities v_n, w_n, mass m, world inertia I_w = R_n I R_n^T):
  unknowns q = (u, theta): the body is at c = c_n + u, R = exp(theta) R_n (theta accumulated from the
      Newton steps' increments, each applied on the left: R <- exp(a dtheta) R)
  its triangles' vertices y_j = c + R (X_j - p) (X_j: body frame, p: centre of mass in it)
  inertia 1/2 m |u - u^|^2 / dt^2 + 1/2 (theta - theta^)^T I_w (theta - theta^) / dt^2,
      u^ = dt v_n + dt^2 g, theta^ = dt w_n (the gyroscopic term left to the rigid world)
  the contact terms (ipctk's barrier and friction on the combined mesh) reach q through dy_j/dq =
      [I, -[r_j]x], r_j = y_j - c: gradient J^T g_y, Hessian J^T H_yy J (the rotation's second-order term
      g_y . d2y/dtheta2 dropped: a Gauss-Newton model, exact in translation).
After the substep the reaction (minus the contact gradient on the body's vertices) goes to the rigid world as
before (``ClothSolver._add_mesh_loads``); at Newton's convergence it is m (v - v_n) - m g dt with v = u / dt,
so the world's semi-implicit Euler step puts the body where the cloth's solve did (c_n + u).
"""

from __future__ import annotations

import numpy as np

from simcli.motion import quat_from_rotvec, quat_to_matrix


def _rotvec_matrix(th: np.ndarray) -> np.ndarray:
    return quat_to_matrix(quat_from_rotvec(np.asarray(th, float)))


def _skew(r: np.ndarray) -> np.ndarray:
    """(k, 3, 3) cross-product matrices [r]x."""
    S = np.zeros(r.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -r[..., 2], r[..., 1]
    S[..., 1, 0], S[..., 1, 2] = r[..., 2], -r[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -r[..., 1], r[..., 0]
    return S


class RigidDofs:
    """The rigid bodies among a ClothSolver's Mesh obstacles (``mobst``): their vertex ranges, body-frame
    vertices and, within a substep, their unknowns."""

    def __init__(self, world, mobst, n_cloth: int):
        self.world = world
        self.bodies = list(world.bodies)
        self.nb = len(self.bodies)
        self.n = n_cloth
        first = len(mobst.index)  # entries past the colliders are the bodies, in world order
        self.ranges = [(mobst.offsets[first + k], mobst.offsets[first + k + 1]) for k in range(self.nb)]
        self.Xb = [
            mobst.V0[lo:hi] - np.asarray(b.pivot, float) for b, (lo, hi) in zip(self.bodies, self.ranges)
        ]
        self.end = None  # (c, R) of each body where the last substep's solve left it

    # ------------------------------------------------------------------ substep
    def start(self, dt: float, g: np.ndarray) -> None:
        """The bodies' state at the substep's start and the first iterate: where the last solve left them
        (their triangles are where the cloth met them; the rigid world may have moved them a little since,
        by wall or other families' loads), or at their state."""
        self.dt = dt
        self.c_n, self.R_n, self.m, self.Iw, self.uh, self.th_h = [], [], [], [], [], []
        for b in self.bodies:
            s = b.state
            R = quat_to_matrix(s.q)
            self.c_n.append(np.asarray(s.x, float).copy())
            self.R_n.append(R)
            self.m.append(float(b.mass))
            self.Iw.append(R @ b.inertia @ R.T)
            v = np.where(b.lin_fixed, b.v_hold, s.v) if b.lin_fixed.any() else s.v
            self.uh.append(dt * np.asarray(v, float) + dt * dt * np.asarray(g, float) * ~b.lin_fixed)
            self.th_h.append(dt * np.asarray(s.w, float))
        self.u = [np.zeros(3) for _ in self.bodies]
        self.th = [np.zeros(3) for _ in self.bodies]
        self.R = [R.copy() for R in self.R_n]
        if self.end is not None:
            for k in range(self.nb):
                c_e, R_e = self.end[k]
                self.u[k] = c_e - self.c_n[k]
                self.R[k] = R_e.copy()
                self.th[k] = _log_rotation(R_e @ self.R_n[k].T)

    def positions(self, u=None, R=None) -> list[np.ndarray]:
        """Each body's vertices (world) at (u, R) (default: the current iterate)."""
        u = self.u if u is None else u
        R = self.R if R is None else R
        return [self.c_n[k] + u[k] + self.Xb[k] @ R[k].T for k in range(self.nb)]

    def write(self, vobs: np.ndarray, u=None, R=None) -> None:
        for (lo, hi), y in zip(self.ranges, self.positions(u, R)):
            vobs[lo:hi] = y

    def trial(self, a: float, p: np.ndarray):
        """(u, R, theta) after a step a along p (6 nb: du, dtheta per body)."""
        u, R, th = [], [], []
        for k in range(self.nb):
            du, dth = p[6 * k : 6 * k + 3], p[6 * k + 3 : 6 * k + 6]
            u.append(self.u[k] + a * du)
            R.append(_rotvec_matrix(a * dth) @ self.R[k])
            th.append(self.th[k] + a * dth)
        return u, R, th

    def accept(self, state) -> None:
        self.u, self.R, self.th = state

    def finish(self) -> None:
        self.end = [(self.c_n[k] + self.u[k], self.R[k].copy()) for k in range(self.nb)]

    # ------------------------------------------------------------------ the potential's body terms
    def energy(self, u=None, th=None) -> float:
        u = self.u if u is None else u
        th = self.th if th is None else th
        e = 0.0
        for k in range(self.nb):
            du, dth = u[k] - self.uh[k], th[k] - self.th_h[k]
            e += 0.5 * (self.m[k] * du @ du + dth @ self.Iw[k] @ dth) / self.dt**2
        return e

    def fixed_mask(self) -> np.ndarray:
        """(6 nb,) True where a degree of freedom is held (fixed_dofs): moved at its prescribed rate by a
        Dirichlet step (held_offset), as pinned cloth vertices are."""
        out = np.zeros(6 * self.nb, bool)
        for k, b in enumerate(self.bodies):
            out[6 * k : 6 * k + 3] = b.lin_fixed
            out[6 * k + 3 : 6 * k + 6] = b.ang_fixed
        return out

    def held_offset(self) -> np.ndarray:
        """(6 nb,) the held degrees of freedom's prescribed motion still to make in this substep (u^ and
        theta^ are the held velocities times dt: the body moves as the rigid world moves it), 0 elsewhere."""
        out = np.zeros(6 * self.nb)
        for k, b in enumerate(self.bodies):
            out[6 * k : 6 * k + 3] = np.where(b.lin_fixed, self.uh[k] - self.u[k], 0.0)
            out[6 * k + 3 : 6 * k + 6] = np.where(b.ang_fixed, self.th_h[k] - self.th[k], 0.0)
        return out

    def gradient(self, g_obs: np.ndarray) -> np.ndarray:
        """(6 nb,) gradient of the potential in the body unknowns from the contact gradient on every obstacle
        vertex (nm, 3) and the inertia."""
        out = np.zeros(6 * self.nb)
        for k, (lo, hi) in enumerate(self.ranges):
            gy = g_obs[lo:hi]
            r = self.Xb[k] @ self.R[k].T
            out[6 * k : 6 * k + 3] = gy.sum(axis=0) + self.m[k] * (self.u[k] - self.uh[k]) / self.dt**2
            out[6 * k + 3 : 6 * k + 6] = (
                np.cross(r, gy).sum(axis=0) + self.Iw[k] @ (self.th[k] - self.th_h[k]) / self.dt**2
            )
        return out

    def jacobian(self, nm: int):
        """Sparse (3 nm, 6 nb) dy/dq of the obstacle vertices (rows of non-body obstacles empty)."""
        import scipy.sparse as sp

        rows, cols, vals = [], [], []
        for k, (lo, hi) in enumerate(self.ranges):
            r = self.Xb[k] @ self.R[k].T
            nv = hi - lo
            vi = np.arange(lo, hi)
            for a in range(3):  # translation: identity
                rows.append(3 * vi + a)
                cols.append(np.full(nv, 6 * k + a))
                vals.append(np.ones(nv))
            S = -_skew(r)  # dy/dtheta = -[r]x
            for a in range(3):
                for b in range(3):
                    rows.append(3 * vi + a)
                    cols.append(np.full(nv, 6 * k + 3 + b))
                    vals.append(S[:, a, b])
        return sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * nm, 6 * self.nb)
        )

    def inertia_blocks(self):
        """(6 nb, 6 nb) dense block diagonal of the inertia terms' Hessian."""
        H = np.zeros((6 * self.nb, 6 * self.nb))
        for k in range(self.nb):
            H[6 * k : 6 * k + 3, 6 * k : 6 * k + 3] = np.eye(3) * self.m[k] / self.dt**2
            H[6 * k + 3 : 6 * k + 6, 6 * k + 3 : 6 * k + 6] = self.Iw[k] / self.dt**2
        return H

    def step_size(self, pb: np.ndarray) -> float:
        """Largest displacement a Newton step pb moves a body's vertex by (translation + rotation x reach)."""
        out = 0.0
        for k in range(self.nb):
            reach = float(np.linalg.norm(self.Xb[k], axis=1).max())
            out = max(
                out,
                float(np.abs(pb[6 * k : 6 * k + 3]).max())
                + float(np.linalg.norm(pb[6 * k + 3 : 6 * k + 6])) * reach,
            )
        return out

    def residual(self, gb: np.ndarray) -> float:
        """Largest acceleration-like residual of the bodies' rows: |g_u| / m and |g_theta| / (m r), r the
        body's radius of gyration about its largest principal axis (sqrt(I_max / m))."""
        out = 0.0
        for k in range(self.nb):
            out = max(out, float(np.abs(gb[6 * k : 6 * k + 3]).max()) / self.m[k])
            Imax = float(np.linalg.eigvalsh(self.Iw[k]).max())
            r2 = Imax / self.m[k]
            out = max(out, float(np.abs(gb[6 * k + 3 : 6 * k + 6]).max()) * r2**0.5 / Imax)
        return out


def _log_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation vector of R."""
    c = np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0)
    ang = float(np.arccos(c))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if ang < 1e-9:
        return 0.5 * w
    return ang / (2.0 * np.sin(ang)) * w
