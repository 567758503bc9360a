"""Implicit FEM: backward Euler as minimisation of the incremental potential

    E(x) = sum_i m_i / (2 h^2) |x_i - xhat_i|^2 + sum_e V_e psi(F_e(x)) - f_ext . x + contact penalty,
    xhat = x_n + h v_n + h^2 g,

by Newton's method: each Newton step solves H dx = -grad E with PCG (3x3 block-Jacobi preconditioner,
the element Hessians projected to positive semi-definite, applied matrix-free from the per-element
singular-value-frame data), then an Armijo back-tracking line search on E. Newton stops when the
residual has fallen by ``newton_tol`` relative to the substep's first one or below ``newton_atol``
(largest |residual| / vertex mass); PCG at relative residual ``pcg_tol``. Both have safety caps that
are counted when hit. Held components are removed from the system (their residual and search
direction are zero). Contact: a penalty kappa_i / 2 phi^2 (phi < 0) per vertex, kappa_i =
contact_stiffness m_i / h^2; Coulomb friction is applied to the velocity afterwards.

Rayleigh damping enters as the dissipation potential h R((x - x_n) / h) (R = v^T D v / 2, whose gradient
is D (x - x_n) / h, i.e. minus the damping force at the end-of-step velocity):
mass-proportional alpha m_i |x_i - x_n,i|^2 / (2 h); stiffness-proportional, per element,
V_e J_n beta / h (mu |sym G|^2 + lam / 2 tr(G)^2), G = (F - F_n) F_n^-1 = h L (the spatial velocity
gradient with F lagged at the substep start, J_n = det F_n clamped at 1e-3 as in the explicit
integrator), mu, lam the material's Lame parameters: beta x the small-strain stiffness, zero for a
translation and of second order in the rotation increment for a rigid rotation. Both are quadratic in x,
so Newton's Hessian and the line search's energy include them exactly.

Implicit midpoint (``integrator: implicit_midpoint``): x_{n+1} = x_n + h (v_n + v_{n+1}) / 2,
v_{n+1} = v_n + h a(x_mid, v_mid) with x_mid = (x_n + x_{n+1}) / 2, v_mid = (x_{n+1} - x_n) / h. It is the
composition of a backward Euler half step and an explicit (forward) Euler half step (Hairer, Lubich and
Wanner, Geometric Numerical Integration, 2nd ed. 2006, sec. II.4, the midpoint rule as the adjoint pair
of Euler half steps): the half step solves for x_mid exactly the minimisation above with h/2 in place of h
(same residual, Hessian, line search and stopping rules, the mass term m / (2 (h/2)^2) |x - xhat|^2 with
xhat = x_n + (h/2) v_n + (h/2)^2 g), then x_{n+1} = 2 x_mid - x_n and v_{n+1} = 2 (x_mid - x_n) / (h/2) -
v_n. Second order, symplectic, A-stable, no numerical damping; it keeps quadratic invariants (the angular
momentum of a free body) and the energy of linear dynamics exactly. Rayleigh damping acts at the midpoint
velocity (x_mid - x_n) / (h/2) = v_mid, the forces at x_mid (the trapezoidal/midpoint damping). Held
components follow their path at the midpoint and the end. Contact: the penalty acts on the end-of-step
position x_{n+1} = 2 x_mid - x_n (kappa_i / 8 phi(2 x - x_n)^2 in the half step's potential, kappa_i =
contact_stiffness m_i / (h/2)^2), as backward Euler's does on its end position: evaluated at x_mid it let
x_{n+1} sink deep into the floor and each impact gained energy (a block dropped on the floor bounced
back with twice its impact energy); friction is applied to v_{n+1}.

Guard: the midpoint rule keeps energy for linear dynamics only; when its extrapolation x_{n+1} = 2 x_mid -
x_n leaves an element inverted (det F <= 0) the step is taken again by backward Euler from (x_n, v_n)
(counted as ``midpoint_fallbacks`` in run.json): without it a block hitting a sphere at 20 m/s
(configs/hard/fem_fast_impact.yaml) gained energy until vertices flew at 120 m/s.

Convergence tests need the residual on the host: one small read-back per PCG and Newton iteration
(the only host syncs inside a substep in simcli; the explicit integrator has none).
"""

import math
import os
import sys

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.solvers.fem.contact import friction_velocity, make_add_load, make_nearest
from simcli.solvers.fem.models import apply_dP, cofactor

with stdout_to_stderr():
    import taichi as ti

ARMIJO_C = 1e-4
MAX_HALVINGS = 20
DEBUG = bool(os.environ.get("SIMCLI_FEM_DEBUG"))


class ImplicitIntegrator:
    def __init__(self, s) -> None:
        self.s = s
        f = s.f
        n, m, nc = s.n, s.mk, s.nc  # kernel elements and their corners (tet10: quadrature points, 10 nodes)
        V3 = lambda k: ti.Vector.field(3, f, shape=k)  # noqa: E731
        M3 = lambda k: ti.Matrix.field(3, 3, f, shape=k)  # noqa: E731
        self.xn, self.xhat, self.g, self.d, self.r, self.z, self.p, self.q = (V3(n) for _ in range(8))
        self.Pinv = M3(n)
        self.hU, self.hV, self.hS = M3(m), M3(m), M3(m)
        self.hls, self.hlt = V3(m), V3(m)
        self.db = M3(nc * m)  # per element corner: diagonal block of the element Hessian
        self.rotated = s.opts.preconditioner == "rotated_rest"
        self.k0 = M3(nc * m if self.rotated else 1)  # rest stiffness diagonal blocks (rotated_rest)
        if self.rotated:
            self.k0.from_numpy(s.rest_diagonal_blocks().astype(s.npf))
        self.dmin = ti.field(f, shape=())
        self.cn = V3(n)  # contact normal x kappa-sqrt marker (zero when not in contact)
        self.ck = ti.field(f, shape=n)  # contact stiffness in effect
        self.red = ti.field(ti.f64, shape=5)
        self.alpha = float(s.opts.mass_damping)
        self.beta = float(s.opts.damping)
        # stiffness damping: per element F_n^-1 (as cof(F_n)^T / J_n) and J_n, J_n clamped at 1e-3
        self.dA = M3(m if self.beta > 0 else 1)
        self.dJ = ti.field(f, shape=m if self.beta > 0 else 1)
        self.opts = s.opts
        self.midpoint = s.opts.integrator == "implicit_midpoint"
        self.vn = V3(n if self.midpoint else 1)  # implicit midpoint: v_n, kept for a backward Euler retry
        # implicit midpoint: the contact penalty acts on c x - (c - 1) x_n: c = 2 in the half step (the end
        # position), c = 1 in a backward Euler retry (its own end position)
        self.cw = ti.field(f, shape=())
        self.cw[None] = 2.0
        # a Newton step smaller than this [m] moves positions by their round-off only
        self.round_off = (1e-6 if f == ti.f32 else 1e-13) * max(s.extent, 1e-3)
        # the residual per vertex mass holds m / h^2 (x - xhat): positions rounded to eps |x| put a floor of
        # about eps |x|max / h^2 [m/s^2] under it (0.03 m/s^2 in f32 at |x| = 0.3 m, h = 1e-3 s); Newton
        # stops there too rather than spend a PCG solve on round-off
        lo, hi = s.scene.domain.bounds(3)
        xmax = max([abs(c) for c in lo + hi] + [float(np.abs(s.x0).max())])
        self.acc_floor_h2 = 2.0 * (2.0**-23 if f == ti.f32 else 2.0**-52) * xmax  # / h^2 at each substep
        self._make()
        self._compile()

    def _make(self) -> None:
        s = self.s
        f = s.f
        n, m, nc = s.n, s.mk, s.nc
        deformation_plus, corner_grad = s.deformation_plus, s.corner_grad
        x, v, xr, free, vfix, fext, mass = s.x, s.v, s.xr, s.free_f, s.vfix_f, s.fext_f, s.mass_f
        vol, B, gravity = s.vol_f, s.B_f, s.gravity
        deformation, law_call, law_hessian, scatter, gather = (
            s.deformation,
            s.law_call,
            s.law_hessian,
            s.scatter_columns,
            s.gather,
        )
        xn, xhat, g, d, r, z, p, q, Pinv = (
            self.xn,
            self.xhat,
            self.g,
            self.d,
            self.r,
            self.z,
            self.p,
            self.q,
            self.Pinv,
        )
        hU, hV, hS, hls, hlt, db, cn, ck, red = (
            self.hU,
            self.hV,
            self.hS,
            self.hls,
            self.hlt,
            self.db,
            self.cn,
            self.ck,
            self.red,
        )
        poses = s.poses
        nearest = make_nearest(s.scene, 3, poses)
        add_load = make_add_load(poses)
        moving, named = poses.any_moving, poses.any_named
        kc = float(self.opts.contact_stiffness)
        ray_a, ray_b = self.alpha, self.beta
        has_muscle, active_dP = s.has_muscle, s.active_dP
        dA, dJ, mid, mu0, lam0 = self.dA, self.dJ, s.mid_f, s.mat_mu0, s.mat_lam0
        rotated, k0, dmin, tet = self.rotated, self.k0, self.dmin, s.tet_f
        midpoint, cw = self.midpoint, self.cw

        @ti.func
        def damp_pk1(e, dF):
            """beta J_n sigma'(dF A) A^T with sigma'(G) = 2 mu sym G + lam tr(G) I, A = F_n^-1: the first
            Piola-Kirchhoff damping stress times h for the deformation increment dF (linear in dF)."""
            A = dA[e]
            G = dF @ A
            k = mid[e]
            sig = mu0[k] * (G + G.transpose()) + lam0[k] * G.trace() * ti.Matrix.identity(float, 3)
            return ray_b * dJ[e] * sig @ A.transpose()

        @ti.func
        def damp_energy(e, dF):
            G = dF @ dA[e]
            k = mid[e]
            S = 0.5 * (G + G.transpose())
            return ray_b * dJ[e] * (mu0[k] * (S * S).sum() + 0.5 * lam0[k] * G.trace() ** 2)

        @ti.kernel
        def begin(dt: f, t: f):
            if ti.static(ray_b > 0):
                for e in range(m):
                    F = deformation(e, x)
                    J = ti.max(F.determinant(), 1e-3)
                    dA[e] = cofactor(F).transpose() / J
                    dJ[e] = J
            for i in range(n):
                xn[i] = x[i]
                xhat[i] = x[i] + dt * v[i] + dt * dt * gravity[None]
                xi = x[i]  # Newton starts from x_n or xhat, whichever has the lower energy (substep())
                fr = free[i]
                for c in ti.static(range(3)):
                    if fr[c] == 0:
                        xi[c] = xr[i][c] + vfix[i][c] * (t + dt)
                x[i] = xi
                # the step to free flight's backward-Euler solution, mass damping included (held components
                # kept)
                d[i] = (x[i] + dt * (v[i] + dt * gravity[None]) / (1.0 + ray_a * dt) - xi) * fr

        @ti.kernel
        def predictor_min_det() -> f:
            """Smallest det F over the elements at x + d (the free-flight predictor of begin)."""
            dmin[None] = 1e30
            for e in range(m):
                if ti.static(nc == 4):
                    t4 = tet[e]
                    x0 = x[t4[0]] + d[t4[0]]
                    Ds = ti.Matrix.cols(
                        [x[t4[1]] + d[t4[1]] - x0, x[t4[2]] + d[t4[2]] - x0, x[t4[3]] + d[t4[3]] - x0]
                    )
                    ti.atomic_min(dmin[None], (Ds @ B[e]).determinant())
                else:  # tet10: det F at the quadrature points
                    ti.atomic_min(dmin[None], deformation_plus(e, x, d).determinant())
            return dmin[None]

        @ti.kernel
        def assemble(dt: f):
            """Gradient g and contact state; red[0] = |g|^2, red[1] = max |g_i| / m_i."""
            for e in range(m):
                F = deformation(e, x)
                P = law_call(e, F, "pk1")
                if ti.static(ray_b > 0):
                    P += damp_pk1(e, F - deformation(e, xn)) / dt
                scatter(e, vol[e] * P @ B[e].transpose())
            red[0] = 0.0
            red[1] = 0.0
            for i in range(n):
                mi = mass[i]
                gi = mi / (dt * dt) * (x[i] - xhat[i]) + gather(i) - fext[i]
                if ti.static(ray_a > 0):
                    gi += ray_a * mi / dt * (x[i] - xn[i])
                k = 0.0
                if ti.static(not midpoint):
                    phi, nrm, kind, mu, _vw, _idx = nearest(x[i])
                    if phi < 0:
                        k = kc * mi / (dt * dt)
                        gi += k * phi * nrm
                    cn[i] = nrm
                else:
                    # implicit midpoint: the penalty acts on the end-of-step position c x - (c - 1) x_n, c = 2
                    # (energy kc m / (2 c^2 dt^2) phi^2 in the half step's unknown x: gradient k / c phi n,
                    # Hessian k n n^T); c = 1 in a backward Euler retry
                    c = cw[None]
                    phi, nrm, kind, mu, _vw, _idx = nearest(c * x[i] - (c - 1.0) * xn[i])
                    if phi < 0:
                        k = kc * mi / (dt * dt)
                        gi += k / c * phi * nrm
                    cn[i] = nrm
                ck[i] = k
                gi = gi * free[i]
                g[i] = gi
                red[0] += ti.cast(gi.dot(gi), ti.f64)
                ti.atomic_max(red[1], ti.cast(gi.norm() / mi, ti.f64))

        @ti.kernel
        def hessian(dt: f):
            """Element Hessian data (singular-value frame) and the block-Jacobi preconditioner, at x (after
            assemble, whose contact state it uses): only when Newton has to take a step."""
            for e in range(m):
                F = deformation(e, x)
                U, V, Hs, ls, lt = law_hessian(e, F)
                hU[e], hV[e], hS[e], hls[e], hlt[e] = U, V, Hs, ls, lt
                Bt = B[e].transpose()
                if ti.static(rotated):
                    # the rest stiffness's diagonal blocks turned by the element's rotation R = U V^T: two
                    # 3x3 products per corner instead of three dP/dF applications (the exact blocks)
                    R = U @ V.transpose()
                    scale = 1.0
                    if ti.static(ray_b > 0):
                        scale += ray_b / dt
                    for a in ti.static(range(nc)):
                        db[nc * e + a] = scale * (R @ k0[nc * e + a] @ R.transpose())
                if ti.static(not rotated):
                    for a in range(nc):
                        ga = ti.Vector.zero(float, 3)  # gradient of corner a's shape function
                        if ti.static(nc == 10):
                            ga = corner_grad(e, a)
                        else:
                            if a == 0:
                                for j in ti.static(range(3)):
                                    ga[j] = -(Bt[0, j] + Bt[1, j] + Bt[2, j])
                            else:
                                for j in ti.static(range(3)):
                                    ga[j] = Bt[a - 1, j]
                        blk = ti.Matrix.zero(float, 3, 3)
                        for c in range(3):
                            E = ti.Matrix.zero(float, 3, 3)
                            for j in ti.static(range(3)):
                                E[c, j] = ga[j]
                            dP = apply_dP(U, V, Hs, ls, lt, E)
                            if ti.static(ray_b > 0):
                                dP += damp_pk1(e, E) / dt
                            if ti.static(has_muscle):
                                dP += active_dP(e, E)
                            col = vol[e] * dP @ ga
                            for rr in ti.static(range(3)):
                                blk[rr, c] = col[rr]
                        db[nc * e + a] = blk
            for i in range(n):
                mi = mass[i]
                D = ti.Matrix.identity(float, 3) * (mi / (dt * dt))
                if ti.static(ray_a > 0):
                    D += ti.Matrix.identity(float, 3) * (ray_a * mi / dt)
                for qq in range(s.adj_start_f[i], s.adj_start_f[i + 1]):
                    k = s.adj_f[qq]
                    if k < 0:  # never: keeps the loop scalar (solvers/sph/neighbours.py, Scalar pair loops)
                        break
                    D += db[k]
                if ck[i] > 0:
                    D += ck[i] * cn[i].outer_product(cn[i])
                fr = free[i]
                for a in ti.static(range(3)):
                    if fr[a] == 0:
                        for b in ti.static(range(3)):
                            D[a, b] = 0.0
                            D[b, a] = 0.0
                        D[a, a] = 1.0
                Pinv[i] = D.inverse()

        @ti.kernel
        def pcg_init() -> ti.f64:
            red[2] = 0.0
            rz = ti.cast(0.0, ti.f64)
            for i in range(n):
                d[i] = ti.Vector.zero(float, 3)
                r[i] = -g[i]
                z[i] = Pinv[i] @ r[i]
                p[i] = z[i]
                rz += ti.cast(r[i].dot(z[i]), ti.f64)
                red[2] += ti.cast(r[i].dot(r[i]), ti.f64)
            return rz

        @ti.kernel
        def matvec(beta: f, first: ti.i32, dt: f) -> ti.f64:
            """p = z + beta p (after the first iteration), q = H p; returns p . q."""
            if first == 0:
                for i in range(n):
                    p[i] = z[i] + beta * p[i]
            for e in range(m):
                dF = deformation(e, p)
                dP = apply_dP(hU[e], hV[e], hS[e], hls[e], hlt[e], dF)
                if ti.static(ray_b > 0):
                    dP += damp_pk1(e, dF) / dt
                if ti.static(has_muscle):
                    dP += active_dP(e, dF)
                scatter(e, vol[e] * dP @ B[e].transpose())
            pq = ti.cast(0.0, ti.f64)
            for i in range(n):
                pi = p[i]
                qi = mass[i] / (dt * dt) * pi + gather(i)
                if ti.static(ray_a > 0):
                    qi += ray_a * mass[i] / dt * pi
                if ck[i] > 0:
                    qi += ck[i] * cn[i].dot(pi) * cn[i]
                qi = qi * free[i]
                q[i] = qi
                pq += ti.cast(pi.dot(qi), ti.f64)
            return pq

        @ti.kernel
        def pcg_update(alpha: f) -> ti.f64:
            red[2] = 0.0
            rz = ti.cast(0.0, ti.f64)
            for i in range(n):
                d[i] += alpha * p[i]
                r[i] -= alpha * q[i]
                z[i] = Pinv[i] @ r[i]
                rz += ti.cast(r[i].dot(z[i]), ti.f64)
                red[2] += ti.cast(r[i].dot(r[i]), ti.f64)
            return rz

        @ti.kernel
        def energy(alpha: f, dt: f) -> ti.f64:
            """E(x + alpha d), with red[3] = g . d."""
            red[3] = 0.0
            red[4] = 0.0
            E = ti.cast(0.0, ti.f64)
            for i in range(n):
                q[i] = x[i] + alpha * d[i]  # q is free after PCG: the trial positions
                red[3] += ti.cast(g[i].dot(d[i]), ti.f64)
                ti.atomic_max(red[4], ti.cast(ti.abs(d[i]).max(), ti.f64))
            for e in range(m):
                F = deformation(e, q)
                Ee = law_call(e, F, "energy")
                if ti.static(ray_b > 0):
                    Ee += damp_energy(e, F - deformation(e, xn)) / dt
                E += ti.cast(vol[e] * Ee, ti.f64)
            for i in range(n):
                dx = q[i] - xhat[i]
                Ei = 0.5 * mass[i] / (dt * dt) * dx.dot(dx) - fext[i].dot(q[i])
                if ti.static(ray_a > 0):
                    dn = q[i] - xn[i]
                    Ei += 0.5 * ray_a * mass[i] / dt * dn.dot(dn)
                if ti.static(not midpoint):
                    phi, nrm, kind, mu, _vw, _idx = nearest(q[i])
                    if phi < 0:
                        Ei += 0.5 * kc * mass[i] / (dt * dt) * phi * phi
                else:
                    c = cw[None]
                    phi, nrm, kind, mu, _vw, _idx = nearest(c * q[i] - (c - 1.0) * xn[i])
                    if phi < 0:
                        Ei += 0.5 / (c * c) * kc * mass[i] / (dt * dt) * phi * phi
                E += ti.cast(Ei, ti.f64)
            return E

        @ti.kernel
        def apply(alpha: f):
            for i in range(n):
                x[i] += alpha * d[i]

        @ti.kernel
        def finish(dt: f):
            for i in range(n):
                vi = (x[i] - xn[i]) / dt
                phi, nrm, kind, mu, vw, idx = nearest(x[i])
                if ck[i] > 0 or phi < 0:
                    # normal speed the contact took away over the substep: penalty force x dt / m
                    dvn = ti.max(0.0, -phi) * kc / dt
                    if ti.static(moving or named):
                        # friction on the velocity relative to the obstacle's surface; a named collider
                        # takes the penalty's impulse (-k phi n dt, k = kc m / dt^2) and the friction's
                        v_in = vi
                        vi = friction_velocity(vi - vw, nrm, kind, mu, dvn) + vw
                        if ti.static(named):
                            if phi < 0:
                                add_load(idx, x[i], mass[i] * (phi * kc / dt * nrm + (v_in - vi)))
                    else:
                        vi = friction_velocity(vi, nrm, kind, mu, dvn)
                fr = free[i]
                for c in ti.static(range(3)):
                    if fr[c] == 0:
                        vi[c] = vfix[i][c]
                v[i] = vi

        vn = self.vn

        @ti.kernel
        def save_v():
            for i in range(n):
                vn[i] = v[i]

        @ti.kernel
        def restore():
            for i in range(n):
                x[i] = xn[i]
                v[i] = vn[i]

        @ti.kernel
        def min_det() -> f:
            """Smallest det F over the elements at x."""
            dmin[None] = 1e30
            for e in range(m):
                ti.atomic_min(dmin[None], deformation(e, x).determinant())
            return dmin[None]

        @ti.kernel
        def finish_midpoint(dt: f, t: f):
            """Implicit midpoint's explicit half step: x holds x_mid (the half step's solution, dt = h/2)."""
            for i in range(n):
                y = x[i]
                vm = (y - xn[i]) / dt  # the midpoint velocity
                xi = 2.0 * y - xn[i]
                vi = 2.0 * vm - v[i]
                phi, nrm, kind, mu, vw, idx = nearest(xi)
                if ck[i] > 0 or phi < 0:
                    # normal speed the penalty (at the end position) took away: 2 dt x force / m
                    dvn = ti.max(0.0, -phi) * kc / dt
                    if ti.static(moving or named):
                        # as in finish: friction relative to the obstacle's surface, the load to a named one
                        v_in = vi
                        vi = friction_velocity(vi - vw, nrm, kind, mu, dvn) + vw
                        if ti.static(named):
                            if phi < 0:
                                add_load(idx, xi, mass[i] * (phi * kc / dt * nrm + (v_in - vi)))
                    else:
                        vi = friction_velocity(vi, nrm, kind, mu, dvn)
                fr = free[i]
                for c in ti.static(range(3)):
                    if fr[c] == 0:
                        vi[c] = vfix[i][c]
                        xi[c] = xr[i][c] + vfix[i][c] * (t + 2.0 * dt)
                x[i] = xi
                v[i] = vi

        self.k = dict(
            finish_midpoint=finish_midpoint,
            save_v=save_v,
            restore=restore,
            min_det=min_det,
            begin=begin,
            predictor_min_det=predictor_min_det,
            assemble=assemble,
            hessian=hessian,
            pcg_init=pcg_init,
            matvec=matvec,
            pcg_update=pcg_update,
            energy=energy,
            apply=apply,
            finish=finish,
        )

    def _compile(self) -> None:
        """Compile the kernels a Newton step needs now, at build, rather than inside the first substep that
        takes one (they write only scratch fields here; begin and finish compile in the first substep)."""
        k = self.k
        k["assemble"](1.0)
        k["hessian"](1.0)
        k["pcg_init"]()
        k["matvec"](0.0, 1, 1.0)
        k["pcg_update"](0.0)
        k["energy"](0.0, 1.0)
        k["apply"](0.0)
        k["predictor_min_det"]()

    def substep(self, dt: float, t: float) -> None:
        if self.midpoint:
            # backward Euler half step to x_mid (below, with h/2), then the explicit half step
            h, k = dt, self.k
            k["save_v"]()
            self._solve(0.5 * h, t)
            k["finish_midpoint"](0.5 * h, t)
            if not k["min_det"]() > 0:
                # the extrapolation x_n+1 = 2 x_mid - x_n inverted an element: the midpoint rule is not
                # energy-stable for such large nonlinear steps (energy then grows without bound: a block
                # hitting a sphere at 20 m/s); this step is taken again by backward Euler (counted)
                k["restore"]()
                self.cw[None] = 1.0  # contact on the retry's own end position
                self._solve(h, t)
                self.cw[None] = 2.0
                k["finish"](h)
                st = self.s.stats
                st["midpoint_fallbacks"] = st.get("midpoint_fallbacks", 0) + 1
        else:
            self._solve(dt, t)
            self.k["finish"](dt)
        st = self.s.stats
        if len(st["newton"]) > 100000:
            del st["newton"][:50000], st["pcg"][:50000]

    def _solve(self, dt: float, t: float) -> None:
        """Minimise the backward Euler incremental potential of a step dt from time t (x ends at its
        minimiser; v still holds the start velocity)."""
        k, o, st = self.k, self.opts, self.s.stats
        k["begin"](dt, t)
        # Start Newton from free flight's solution x_n + h (v_n + h g) / (1 + alpha h) when it inverts no
        # element and its incremental potential is below x_n's: exact for a body in free flight (no
        # iteration), and a translation is the slowest error for block-Jacobi PCG to remove. Otherwise
        # (large dt, a body held or resting on something) from x_n: the relative Newton stop is measured
        # from the start, which must not be a far worse point than x_n.
        e_pred = k["energy"](1.0, dt) if k["predictor_min_det"]() > 0 else math.inf
        e_cur = k["energy"](0.0, dt)  # incremental potential at the current iterate
        if e_pred < e_cur:
            k["apply"](1.0)
            e_cur = e_pred
        newton_it, pcg_total = 0, 0
        res0 = None
        while True:
            k["assemble"](dt)
            red = self.red.to_numpy()
            res, acc = math.sqrt(red[0]), red[1]
            if DEBUG:
                print("newton", newton_it, res, acc, file=sys.stderr)
            if res0 is None:
                res0 = res
            if (
                acc <= max(o.newton_atol, self.acc_floor_h2 / (dt * dt))
                or res <= o.newton_tol * res0
                or res == 0.0
            ):
                break
            if newton_it >= o.newton_max_iter:
                st["newton_capped"] += 1
                break
            newton_it += 1
            k["hessian"](dt)
            # PCG: H d = -g
            rz = k["pcg_init"]()
            b2 = float(self.red[2])
            it, beta = 0, 0.0
            while it < o.pcg_max_iter:
                pq = k["matvec"](beta, 1 if it == 0 else 0, dt)
                if not pq > 0:
                    break
                alpha = rz / pq
                rz_new = k["pcg_update"](alpha)
                it += 1
                if float(self.red[2]) <= o.pcg_tol**2 * b2:
                    break
                beta = rz_new / rz
                rz = rz_new
            else:
                st["pcg_capped"] += 1
            pcg_total += it
            # Armijo back-tracking on the incremental potential
            alpha = 1.0
            if o.line_search:
                E0 = e_cur if e_cur is not None else k["energy"](0.0, dt)
                tol = 1e-6 * abs(E0) if self.s.f == ti.f32 else 1e-12 * abs(E0)
                ok, gd = False, None
                for _ in range(MAX_HALVINGS):
                    Ea = k["energy"](alpha, dt)
                    if gd is None:
                        gd = float(self.red[3])  # g . d, the same for every trial
                    if Ea <= E0 + ARMIJO_C * alpha * gd + tol:
                        ok = True
                        e_cur = Ea
                        break
                    alpha *= 0.5
                    st["ls_halvings"] += 1
                # no decrease along a descent direction, or a step below the position round-off:
                # the round-off level is reached (counted as stagnated, not as converged)
                if not ok or alpha * float(self.red[4]) < self.round_off:
                    st["stagnated"] = st.get("stagnated", 0) + 1
                    if ok:
                        k["apply"](alpha)
                    break
            k["apply"](alpha)
        st["newton"].append(newton_it)
        st["pcg"].append(pcg_total)


__all__ = ["ImplicitIntegrator", "np"]
