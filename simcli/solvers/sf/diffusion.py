"""diffuse: implicit viscosity (Stam 1999, backward Euler), (I - nu dt L) u = u*, per velocity
component on its faces, solved by conjugate gradients (the matrix is symmetric positive
definite; any nu dt is stable, so a scene can set a physical Reynolds number).

Boundary conditions enter through two per-face arrays computed once on the host from the face
kinds (``grid.py``): ``K`` (the sum of the couplings c_a = 1/dx_a^2 of the face, -1 for a face
that is not an unknown) and ``B`` (the coupling-weighted prescribed velocities next to it). A
fixed neighbour (wall or collider face) is a Dirichlet value; a sticky wall half a cell away
adds 2 c_a to the diagonal and 2 c_a u_wall to the right-hand side (ghost 2 u_wall - u); a slip
or open face adds nothing (zero shear); periodic neighbours wrap. The unknowns then satisfy

    (1 + nu dt K) u_I - nu dt sum_{free J} c_a u_J = u*_I + nu dt B_I.

All components are solved as one block-diagonal system (one CG loop, one convergence read per
iteration), stopping when ||r||_2 <= viscosity_tolerance ||b||_2.
"""

import math

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.solvers.sf.boundary import Boundary, make_neighbour
from simcli.solvers.sf.grid import Layout, viscosity_operator

with stdout_to_stderr():
    import taichi as ti


class Diffusion:
    def __init__(
        self, layout: Layout, f, bc: Boundary, vel, nu: float, tolerance: float, max_iterations: int = 500
    ) -> None:
        self.layout, self.f, self.bc, self.vel = layout, f, bc, vel
        self.nu, self.tol, self.maxit = float(nu), float(tolerance), int(max_iterations)
        dim = layout.dim
        npf = np.float64 if f == ti.f64 else np.float32
        shape = (dim,) + tuple(c + 3 for c in layout.n)
        off = (0,) + (-1,) * dim

        def ff():
            return ti.field(f, shape=shape, offset=off)

        self.K, self.B, self.r, self.p, self.Ap = ff(), ff(), ff(), ff(), ff()
        self.npf = npf
        self.update_operator()
        self.sc = ti.field(ti.f64, shape=8)  # rr, pAp, bb, rr_new, nu dt, alpha, beta, max |r|
        self._make()

    def update_operator(self) -> None:
        """Upload the viscosity operator of the layout's face kinds (at build; again after moving colliders
        changed them)."""
        ops = [viscosity_operator(self.layout, d) for d in range(self.layout.dim)]
        self.K.from_numpy(np.stack([o[0] for o in ops]).astype(self.npf))
        self.B.from_numpy(np.stack([o[1] for o in ops]).astype(self.npf))

    def _make(self) -> None:
        L, f, bc = self.layout, self.f, self.bc
        dim, n, periodic = L.dim, L.n, L.periodic
        vel, K, B, r, p, Ap, sc = self.vel, self.K, self.B, self.r, self.p, self.Ap, self.sc
        c = [1.0 / h**2 for h in L.dx]
        at = bc.at
        loops = bc.face_loops  # per component: (foreach, sum, sum_max, scaled, sum_scaled)

        nb = make_neighbour(n, periodic)  # face I + s e_a

        @ti.func
        def offdiag(q: ti.template(), d: ti.template(), I, masked: ti.template()):
            s = ti.cast(0.0, f)
            for a in ti.static(range(dim)):
                for t in ti.static((1, -1)):
                    J = at(d, nb(I, a, t))
                    if ti.static(masked):
                        if K[J] >= 0:
                            s += c[a] * q[J]
                    else:
                        s += c[a] * q[J]
            return s

        # slots of sc: 0 rr, 1 pAp, 2 bb, 3 rr_new, 4 nu dt, 5 alpha, 6 beta
        def bodies(d):
            @ti.func
            def start(I, nudt64):
                nudt = ti.cast(nudt64, f)
                J = at(d, I)
                k = K[J]
                ri = ti.cast(0.0, f)
                if k >= 0:
                    ri = nudt * (B[J] - k * vel[J] + offdiag(vel, d, I, True))
                r[J] = ri
                p[J] = ri
                return ti.cast(ri, ti.f64) ** 2

            @ti.func
            def rhs(I, nudt64):
                J = at(d, I)
                v = ti.cast(0.0, ti.f64)
                if K[J] >= 0:
                    v = ti.cast(vel[J] + ti.cast(nudt64, f) * B[J], ti.f64) ** 2
                return v

            @ti.func
            def apply(I, nudt64):
                nudt = ti.cast(nudt64, f)
                J = at(d, I)
                k = K[J]
                a = ti.cast(0.0, f)
                if k >= 0:
                    a = (1.0 + nudt * k) * p[J] - nudt * offdiag(p, d, I, False)
                Ap[J] = a
                return ti.cast(p[J], ti.f64) * a

            @ti.func
            def update(I, alpha64):
                alpha = ti.cast(alpha64, f)
                J = at(d, I)
                ri = r[J]
                if K[J] >= 0:
                    vel[J] += alpha * p[J]
                    ri -= alpha * Ap[J]
                    r[J] = ri
                r64 = ti.cast(ri, ti.f64)
                return r64 * r64, ti.abs(r64)

            @ti.func
            def direction(I, beta64):
                J = at(d, I)
                p[J] = r[J] + ti.cast(beta64, f) * p[J]

            return start, rhs, apply, update, direction

        B_ = [bodies(d) for d in range(dim)]

        @ti.kernel
        def start(nudt: f):
            sc[4] = nudt
            sc[0] = 0.0
            sc[2] = 0.0
            for d in ti.static(range(dim)):
                loops[d][4](B_[d][0], sc, 0, sc, 4)
                loops[d][4](B_[d][1], sc, 2, sc, 4)

        @ti.kernel
        def apply():
            sc[1] = 0.0
            for d in ti.static(range(dim)):
                loops[d][4](B_[d][2], sc, 1, sc, 4)

        @ti.kernel
        def update():
            sc[5] = 0.0
            if sc[1] > 0:
                sc[5] = sc[0] / sc[1]
            sc[3] = 0.0
            sc[7] = 0.0
            for d in ti.static(range(dim)):
                loops[d][2](B_[d][3], sc, 3, 7, sc, 5)

        @ti.kernel
        def direction():
            sc[6] = 0.0
            if sc[0] > 0:
                sc[6] = sc[3] / sc[0]
            for d in ti.static(range(dim)):
                loops[d][3](B_[d][4], sc, 6)
            sc[0] = sc[3]

        @ti.kernel
        def ghosts():
            bc.fill_face_ghosts(vel)

        self._start, self._apply, self._update, self._direction, self._ghosts = (
            start,
            apply,
            update,
            direction,
            ghosts,
        )

    def solve(self, dt: float) -> tuple[int, float]:
        """Diffuse the velocity in place. Returns (iterations, ||r|| / ||b||)."""
        nudt = self.nu * dt
        self._start(nudt)
        s = self.sc.to_numpy()
        bb = max(float(s[2]), 1e-300)
        rel = math.sqrt(float(s[0]) / bb)
        its = 0
        while rel > self.tol and its < self.maxit:
            self._apply()
            self._update()
            its += 1
            s = self.sc.to_numpy()
            rel = math.sqrt(float(s[3]) / bb)
            self._direction()
        self._ghosts()
        return its, rel
