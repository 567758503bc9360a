"""Explicit FEM: symplectic Euler with lumped vertex masses, one kernel launch per substep::

    element forces (per element, into a buffer) -> vertex update (gather, gravity, held components,
    contact projection, position update)

Optional stiffness-proportional damping adds the viscous stress beta (2 mu sym(L) + lam tr(L) I), L the
spatial velocity gradient: zero for any rigid motion, so gravity and spinning are not damped.
Mass-proportional damping (alpha) is applied implicitly to the vertex velocity: v <- v / (1 + alpha dt).
"""

from simcli.backend import stdout_to_stderr
from simcli.colliders import project_out, project_out_e
from simcli.solvers.fem.contact import make_add_load, make_nearest
from simcli.solvers.fem.models import cofactor

with stdout_to_stderr():
    import taichi as ti


class ExplicitIntegrator:
    def __init__(self, s) -> None:
        f = s.f
        x, v, xr, free, vfix, fext, mass = s.x, s.v, s.xr, s.free_f, s.vfix_f, s.fext_f, s.mass_f
        vol, B, mid, mat_mu, mat_lam = s.vol_f, s.B_f, s.mid_f, s.mat_mu0, s.mat_lam0
        gravity = s.gravity
        deformation, law_call, scatter, gather = s.deformation, s.law_call, s.scatter_columns, s.gather
        poses = s.poses
        any_e = any(c.restitution > 0 for c in poses.specs)  # restitution compiled only when some
        nearest6 = make_nearest(s.scene, 3, poses, with_restitution=any_e)

        @ti.func
        def nearest(x):
            if ti.static(any_e):
                return nearest6(x)
            else:
                phi, nrm, kind, mu, vw, idx = nearest6(x)
                return phi, nrm, kind, mu, vw, idx, 0.0

        @ti.func
        def slip(x, v, phi, nrm, mu, e):
            if ti.static(any_e):
                return project_out_e(x, v, phi, nrm, "slip", mu, e)
            else:
                return project_out(x, v, phi, nrm, "slip", mu)

        add_load = make_add_load(poses)
        moving, named = poses.any_moving, poses.any_named
        n, m = s.n, s.mk  # kernel elements (tet10: quadrature points)
        beta = float(s.opts.damping)
        alpha = float(s.opts.mass_damping)

        @ti.kernel
        def substep(dt: f, t: f):
            for e in range(m):
                F = deformation(e, x)
                P = law_call(e, F, "pk1")
                if ti.static(beta > 0):
                    Fdot = deformation(e, v)
                    C = cofactor(F)
                    J = ti.max(F.determinant(), 1e-3)
                    L = Fdot @ C.transpose() / J
                    k = mid[e]
                    sig = beta * (
                        mat_mu[k] * (L + L.transpose())
                        + mat_lam[k] * L.trace() * ti.Matrix.identity(float, 3)
                    )
                    P += sig @ C
                scatter(e, -vol[e] * P @ B[e].transpose())
            for i in range(n):
                fi = gather(i) + fext[i]
                vi = v[i] + dt * (fi / mass[i] + gravity[None])
                if ti.static(alpha > 0):
                    vi /= 1.0 + alpha * dt
                xi = x[i] + dt * vi
                phi, nrm, kind, mu, vw, idx, e_r = nearest(xi)
                if phi < 0:
                    if ti.static(moving or named):
                        # contact on the velocity relative to the obstacle's surface; named colliders
                        # take the momentum the contact removed
                        v_in = vi
                        vr = vi - vw
                        if kind == 1:
                            xi, vr = project_out(xi, vr, phi, nrm, "sticky", mu)
                        else:
                            xi, vr = slip(xi, vr, phi, nrm, mu, e_r)
                        vi = vr + vw
                        if ti.static(named):
                            add_load(idx, xi, mass[i] * (v_in - vi))
                    else:
                        if kind == 1:
                            xi, vi = project_out(xi, vi, phi, nrm, "sticky", mu)
                        else:
                            xi, vi = slip(xi, vi, phi, nrm, mu, e_r)
                fr = free[i]
                for c in ti.static(range(3)):
                    if fr[c] == 0:
                        vi[c] = vfix[i][c]
                        xi[c] = xr[i][c] + vfix[i][c] * (t + dt)
                v[i] = vi
                x[i] = xi

        self._substep = substep

    def substep(self, dt: float, t: float) -> None:
        self._substep(dt, t)
