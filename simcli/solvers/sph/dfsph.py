"""DFSPH (Bender & Koschier 2015, "Divergence-free smoothed particle hydrodynamics"; 2017, "Divergence-free
SPH for incompressible and viscous fluids"), as in SPlisHSPlasH's DFSPH.cpp. A substep::

    neighbours -> density + alpha -> divergence_solve -> non_pressure -> density_solve (pressure) -> advect

* alpha_i = 1 / (|sum_j V_j grad W_ij + sum_b V_b grad W_ib|^2 + sum_j |V_j grad W_ij|^2), V_j = m_j / rho0
  (the factor of eq. 9 of the 2017 paper, per unit rho0).
* A relaxed Jacobi iteration on the stiffness k (velocity update, then the new residual):
  v_i -= dt (sum_j (k_i + k_j) V_j grad W_ij + k_i sum_b V_b grad W_ib) (boundary term as SPlisHSPlasH's),
  k_i += RELAX s_i alpha_i / dt^2 with the residual s_i (per substep, in units of rho0):
  divergence solve: s_i = dt (D rho_i / Dt) / rho0 (only with enough neighbours);
  density solve: s_i = rho_i / rho0 - 1 + dt (D rho_i / Dt) / rho0, the predicted density error.
  With a free surface (clamp_pressure) each solve's total k is kept >= 0 (projected Jacobi: an expanding
  particle gives back stiffness it got, never pulls) and only compression counts as error. The solves stop
  when the mean error is at or below max_divergence_error_percent / max_density_error_percent (at least 1
  and 2 iterations), or at the iteration cap. RELAX = 0.5: without relaxation the projected iteration
  diverged in our tests (SPlisHSPlasH clamps the residual instead, which ratchets the warm-started k up).
* Without a free surface (clamp_pressure false: a confined flow) the solves are preconditioned conjugate
  gradients on A k = s with A = dt^2 D G (D the density rate of a velocity field, G the symmetric pressure
  gradient; D = G^T, so A is symmetric positive semi-definite), alpha as the preconditioner: the relaxed
  Jacobi iteration diverged on that problem at support 3 and hit its cap at support 2.
* gradient_correction (Bonet & Lok 1999): grad W_ij becomes L_i grad W_ij in the density rate (exact for a
  linear velocity field on any full neighbourhood) and the velocity update its adjoint, -dt sum_j V_j (k_i L_i
  + k_j L_j) grad W_ij (pairwise antisymmetric, so momentum is conserved, and still D = G^T for the CG solve).
  Without it the projection dissipates a smooth vortex as the packing changes (docs/SPH.md, Taylor-Green).
  gradient_correction: scalar (session 8) keeps the isotropic part, L_i = c_i I with c_i = dim / trace of the
  moment matrix: the gradient's magnitude on a settled packing (0.98 of the exact in a tank at rest, which
  steepens the hydrostatic pressure by 2%), one number per particle.
* Warm start: each solve starts from the previous substep's total stiffness: the density solve's k times
  DENSITY_WARM = 0.9 (a liquid at rest needs the same k for any dt; the full k, as SPlisHSPlasH, kept a
  resting liquid from settling), the divergence solve's k dt / dt_now halved (as in SPlisHSPlasH). The very
  first density solve starts from each column's hydrostatic k = |g| depth.
* Non-pressure accelerations (gravity, viscosity, surface tension) are computed from this substep's
  divergence-free velocities and applied once, before the density solve. Nothing of a previous substep's
  acceleration is re-applied (Genesis 1.4.5 advects with the acceleration stored by the previous substep).
* Walls (wall_pressure: extrapolated, wall_pressure.py): the boundary particles' own k, the Shepard average of
  the liquid's next to them plus the hydrostatic difference, in the velocity update as -dt sum_b V_b (k_i +
  k_b) grad W_ib; each iteration moves k_b by the average of its increments, the hydrostatic part acts once
  per substep with gravity. The default with a free surface (wall_pressure: auto); akinci has k_i alone.
* Pressure output: p_i = (k_i + k_i^div) rho_i^2 / rho0 with the total stiffness of both solves, the
  pressure whose symmetric SPH force equals their velocity corrections over the substep.
* The error of an iteration is summed in 40-bit fixed point (an integer add is associative), so the
  iteration count does not depend on thread scheduling.

The iteration loops run on the host: one kernel launch per iteration and one scalar read to test the
tolerance (a few microseconds on the CPU, where a launch is synchronous anyway).
"""

import math

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams

with stdout_to_stderr():
    import taichi as ti

FIXED = float(2**40)  # fixed-point scale of the error sums
# a particle's error counts at most this much in the sum (100% of rho0): a sum of n such terms stays below
# 2^63 / 2^40 = 8.4e6 for n < 8 million. Unclamped, the overlapped particles of a liquid sampled inside a
# collider (densities of 6 rho0, stiffness of 1e11) overflowed the sum to a negative error and stopped the
# solve.
ERR_CLAMP = 1.0
WARM = 0.5  # fraction of the previous divergence stiffness a warm start applies (SPlisHSPlasH)
# fraction of the previous density stiffness a warm start applies. With all of it (1.0, as SPlisHSPlasH) a
# liquid at rest never settled: the 2D hydrostatic tank kept 4-6 cm/s of particle noise for 4 s (0.97: the
# same); with 0.9 the noise decays as in WCSPH (1.4 cm/s at 0.5-1 s, 0.7 at 1-2 s, 0.3 at 2 s), and cold
# starts (0) decay alike at 300 iterations per substep. A slightly damped warm start keeps the stiffness from
# carrying stale components from substep to substep. Cost: 20% more density iterations in a dam break (3.15 ->
# 3.77 per substep), none at B2's fixed steps. docs/SPH.md, hydrostatic tank.
DENSITY_WARM = 0.9
RELAX = 0.5  # Jacobi relaxation: the unclamped (projected) iteration diverges without it
BFAC = 1.0  # boundary term of the velocity update: k_i alone, as Akinci et al. 2012 and SPlisHSPlasH
MIN_NEIGHBOURS = {2: 7, 3: 20}  # SPlisHSPlasH: no divergence correction for particles with fewer


def make_dfsph(P: SPHParams, F: SPHFields, fn: SPHFuncs, stats: "SolveStats", n_live):
    """DFSPH's substep: ``(substep, couple_phases)``. ``substep(dt)`` runs the solves (host loops over
    kernel launches, iterations and errors recorded in ``stats``) and the advection; ``couple_phases`` is
    ``(pre_couple, post_couple, v)``, the substep in two halves around a coupling phase and the velocity it
    edits. ``n_live()`` (host) is the active particle count the mean error divides by. Needs every shared
    func in ``fn`` (density.py, non_pressure.py, advect.py; wall_pressure.py, moving.py where the scene
    has them)."""
    f, dim = P.f, P.dim
    rho, p, mid, v, vnew = F.rho, F.p, F.mid, F.v, F.vnew
    nb_cnt, nb_j, nb_s, B, Sb, nbb_cnt = F.nb_cnt, F.nb_j, F.nb_s, F.B, F.Sb, F.nbb_cnt
    x = F.x
    alpha, kk, kacc, kappa, kappav = F.alpha, F.kk, F.kacc, F.kappa, F.kappav
    mat_rho0 = F.mat_rho0
    err_acc = F.err_acc
    clamp = P.clamp_pressure
    warm = P.warm_start
    n = P.n
    N = fn.count  # the active count (emitters, sinks) or the constant n
    min_nb = MIN_NEIGHBOURS[dim]
    DIV, DENS = 0, 1

    kgc, Lm, Lc, kgc_scalar = P.kgc, F.Lm, F.Lc, P.kgc_scalar
    uniform = P.uniform  # one material: the pair terms in their single-material form (bitwise as before)
    # the Jacobi iteration with gradient_correction: scalar keeps k_i c_i beside k_i (written with it in
    # density_change): the velocity update's pairs then gather one number per neighbour instead of two
    # (k_j and c_j), and the constant volume V leaves the pair loop (the same sum to round-off)
    fast_kc = kgc_scalar and uniform and clamp
    kc = ti.field(f, shape=n) if fast_kc else None
    wp = fn.wall_pressure  # extrapolated wall pressure (wall_pressure.py), or None: Akinci's term alone
    ext = wp is not None
    # volume maps with the extrapolated wall pressure (volume_map.py): the boundary's k is the particle's own
    # (each iteration's increment mirrored) plus the hydrostatic term F.Hb, applied once per substep
    Hb = F.Hb
    ext_map = Hb is not None

    @ti.func
    def corr(i, g):
        """L_i g: particle i's corrected gradient (g itself without gradient_correction)."""
        out = g
        if ti.static(kgc_scalar):
            out = Lc[i] * g
        elif ti.static(kgc):
            out = Lm[i] @ g
        return out

    @ti.func
    def density_rate(i):
        """(D rho_i / Dt) / rho0 from the current velocities [1/s]."""
        vi = v[i]
        xi = x[i]
        s = vi.dot(corr(i, B[i])) - Sb[i]
        for k in range(nb_cnt[i]):
            j = nb_j[i, k]
            if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                break
            s += fn.volume_of(j) * (vi - v[j]).dot(corr(i, ((xi - x[j]) * nb_s[i, k])))
        return s

    @ti.func
    def set_increment(i, ki):
        """Particle i's stiffness increment k_i (and k_i c_i beside it with the scalar correction)."""
        kk[i] = ki
        if ti.static(fast_kc):
            kc[i] = ki * Lc[i]

    @ti.func
    def warm_increment(i, dt, mode: ti.template()):
        """The first increment of a warm-started solve: the previous substep's total stiffness of the same
        solve, WARM of the divergence solve's (kept dt independent: kappav = k dt) and DENSITY_WARM of the
        density solve's."""
        ki = ti.cast(0.0, f)
        if ti.static(mode == DIV):
            ki = WARM * kappav[i] / dt
        else:
            ki = DENSITY_WARM * kappa[i]
        return ki

    @ti.func
    def density_change(i, dt, mode: ti.template()):
        """Residual s_i of particle i (added to the error sum where it is a compression) and its stiffness
        increment k_i. With a free surface (clamp_pressure) the total stiffness of a solve is projected onto
        k >= 0 (projected Jacobi): a residual expansion lowers a particle's stiffness down to zero but never
        pulls. (A warm-started solve's first increment is warm_increment's, without this residual.)"""
        s = density_rate(i) * dt  # per substep: the density change this substep, in units of rho0
        if ti.static(mode == DENS):
            s += rho[i] / mat_rho0[mid[i]] - 1.0
        elif ti.static(clamp):  # noqa: SIM102 - compile-time, then run-time test
            if nb_cnt[i] + nbb_cnt[i] < min_nb:  # a deficient neighbourhood: no divergence correction
                s = ti.min(s, 0.0)
        err = s
        if ti.static(clamp):
            err = ti.max(s, 0.0)
        ti.atomic_add(err_acc[None], ti.cast(ti.min(ti.abs(err), ERR_CLAMP) * FIXED, ti.i64))
        ki = RELAX * s * alpha[i] / (dt * dt)
        if ti.static(clamp):
            ki = ti.max(ki, -kacc[i])  # total stiffness kacc + k stays >= 0
        set_increment(i, ki)

    @ti.func
    def pressure_gradient(i, k_: ti.template(), g):
        """g plus the liquid's part of the symmetric pressure gradient of the stiffness field k_ at particle i
        (before -dt): sum_j V_j (k_i + k_j) grad W_ij (with gradient_correction: (k_i L_i + k_j L_j) grad
        W_ij). g starts with the walls' part: Akinci's BFAC k_i B_i (plus the extrapolated walls' sum).
        Several materials: sum_j (V_j k_i + (m_j / rho0_i) k_j) grad W_ij, the gradient of the density
        constraints C_i = sum_j V_j W_ij - 1 with multipliers m_i k_i, whose pair forces are opposite
        (SPlisHSPlasH's TimeStepDFSPH: k_i + (rho0_j / rho0_i) k_j); with one material the same."""
        ki = k_[i]
        xi = x[i]  # grad W_ij = (x_i - x_j) s_ij (the list's factor)
        if ti.static(kgc_scalar):  # (k_i c_i + k_j c_j) grad W_ij
            kci = ki * Lc[i]
            for k in range(nb_cnt[i]):
                j = nb_j[i, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                if ti.static(uniform):
                    g += (kci + k_[j] * Lc[j]) * fn.volume_of(j) * ((xi - x[j]) * nb_s[i, k])
                else:
                    g += (fn.volume_of(j) * kci + fn.mass_of(j) / mat_rho0[mid[i]] * k_[j] * Lc[j]) * (
                        (xi - x[j]) * nb_s[i, k]
                    )
        elif ti.static(kgc):
            kLi = ki * Lm[i]
            for k in range(nb_cnt[i]):
                j = nb_j[i, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                if ti.static(uniform):
                    g += fn.volume_of(j) * ((kLi + k_[j] * Lm[j]) @ ((xi - x[j]) * nb_s[i, k]))
                else:
                    g += (fn.volume_of(j) * kLi + (fn.mass_of(j) / mat_rho0[mid[i]] * k_[j]) * Lm[j]) @ (
                        (xi - x[j]) * nb_s[i, k]
                    )
        else:
            for k in range(nb_cnt[i]):
                j = nb_j[i, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                if ti.static(uniform):
                    g += (ki + k_[j]) * fn.volume_of(j) * ((xi - x[j]) * nb_s[i, k])
                else:
                    g += (fn.volume_of(j) * ki + fn.mass_of(j) / mat_rho0[mid[i]] * k_[j]) * (
                        (xi - x[j]) * nb_s[i, k]
                    )
        return g

    @ti.func
    def velocity_update(i, dt):
        ki = kk[i]
        dv = BFAC * ki * corr(i, B[i])
        if ti.static(ext):
            dv += wp.wall_sum(i, wp.bval)  # the walls' k: the average of the liquid's next to them
        if ti.static(ext_map):
            # the map's boundary k: the Shepard average of the liquid's next to the particle (its own
            # included), as boundary particles' extrapolated k (volume_map.py, shepard_k)
            dv += fn.map_wall_k(i, kk) * B[i]
        if ti.static(fast_kc):
            # pressure_gradient's scalar-correction sum, V sum_j (k_i c_i + k_j c_j) s_ij (x_i - x_j), with
            # k_j c_j read from kc (one gather instead of k_j and c_j) and V out of the loop
            xi = x[i]
            kci = kc[i]
            acc = ti.Vector.zero(f, dim)
            for k in range(nb_cnt[i]):
                j = nb_j[i, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                acc += ((kci + kc[j]) * nb_s[i, k]) * (xi - x[j])
            v[i] -= dt * (dv + fn.volume_of(i) * acc)
        else:
            v[i] -= dt * pressure_gradient(i, kk, dv)
        kacc[i] += ki

    # ---- conjugate gradients for a liquid without a free surface (clamp_pressure false): the unprojected
    # pressure problem A k = s, A = dt^2 D G (D the density rate of a velocity field, G the symmetric
    # pressure gradient: D = G^T, so A is symmetric positive semi-definite), Jacobi (alpha) preconditioned.
    # Relaxed Jacobi diverges on it at support 3 and stalls at support 2; CG converges. Sums are serial in
    # f64 so that the iteration count does not depend on threads.
    use_cg = not clamp
    if use_cg:
        dvt = ti.Vector.field(dim, f, shape=n)
        cg_r, cg_z, cg_p, cg_Ap = (ti.field(f, shape=n) for _ in range(4))
        cg_s = ti.field(ti.f64, shape=3)  # r.z, p.Ap, alpha

    @ti.func
    def residual(i, dt, mode: ti.template()):
        s = density_rate(i) * dt
        if ti.static(mode == DENS):
            s += rho[i] / mat_rho0[mid[i]] - 1.0
        return s

    @ti.func
    def serial_dot(a, b, slot):
        acc = ti.cast(0.0, ti.f64)
        ti.loop_config(serialize=True)
        for i in range(N()):
            acc += ti.cast(a[i], ti.f64) * ti.cast(b[i], ti.f64)
        cg_s[slot] = acc

    @ti.func
    def cg_start(dt, mode: ti.template()):
        for i in range(N()):
            r = residual(i, dt, mode)
            cg_r[i] = r
            cg_z[i] = alpha[i] * r
            cg_p[i] = cg_z[i]
        serial_dot(cg_r, cg_z, 0)

    @ti.func
    def cg_iteration(dt):
        for i in range(N()):  # dvt = -dt G p
            dvt[i] = -dt * pressure_gradient(i, cg_p, BFAC * cg_p[i] * corr(i, B[i]))
        for i in range(N()):  # Ap = -dt D(dvt) = dt^2 D G p
            dv = dvt[i]
            xi = x[i]
            d = dv.dot(corr(i, B[i]))
            for k in range(nb_cnt[i]):
                j = nb_j[i, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                d += fn.volume_of(j) * (dv - dvt[j]).dot(corr(i, ((xi - x[j]) * nb_s[i, k])))
            cg_Ap[i] = -dt * d
        serial_dot(cg_p, cg_Ap, 1)
        a = ti.cast(0.0, ti.f64)
        if cg_s[1] > 0:
            a = cg_s[0] / cg_s[1]
        af = ti.cast(a, f)
        err_acc[None] = 0
        for i in range(N()):
            kacc[i] += af * cg_p[i]
            v[i] += af * dvt[i]
            r = cg_r[i] - af * cg_Ap[i]
            cg_r[i] = r
            cg_z[i] = alpha[i] * r
            ti.atomic_add(err_acc[None], ti.cast(ti.min(ti.abs(r), ERR_CLAMP) * FIXED, ti.i64))
        rz_old = cg_s[0]
        serial_dot(cg_r, cg_z, 0)
        beta = ti.cast(0.0, f)
        if rz_old > 0:
            beta = ti.cast(cg_s[0] / rz_old, f)
        for i in range(N()):
            cg_p[i] = cg_z[i] + beta * cg_p[i]

    @ti.func
    def relax(dt, mode: ti.template()):
        """One Jacobi step: the velocities from the current stiffness, then the residual after it."""
        if ti.static(ext):
            wp.update(kk)
        for i in range(N()):
            velocity_update(i, dt)
        err_acc[None] = 0
        for i in range(N()):
            density_change(i, dt, mode)

    @ti.func
    def solve_begin(dt, mode: ti.template(), copy_v: ti.template()):
        """First residual, then (warm start) the previous substep's stiffness and the residual after it.
        copy_v: v = vnew first (the density solve: the non-pressure accelerations' velocity), in the same
        loop when the warm start reads no neighbour."""
        if ti.static(copy_v and not warm):
            for i in range(N()):
                v[i] = vnew[i]
        err_acc[None] = 0
        for i in range(N()):
            if ti.static(copy_v and warm):
                v[i] = vnew[i]
            kacc[i] = 0.0
            if ti.static(warm):
                # the warm start's stiffness only: the first residual would be discarded (relax below
                # resets the error sum and computes the residual after the warm start), so its pass over
                # the neighbours is skipped
                set_increment(i, warm_increment(i, dt, mode))
            else:
                density_change(i, dt, mode)
        if ti.static(warm):
            relax(dt, mode)
        if ti.static(use_cg):
            cg_start(dt, mode)

    @ti.func
    def iteration(dt, mode: ti.template()):
        if ti.static(use_cg):
            cg_iteration(dt)
        else:
            relax(dt, mode)

    @ti.func
    def neighbours():
        if ti.static(P.moving_boundary):
            fn.move_boundary()  # moving colliders' boundary particles to this substep's pose (moving.py)
        fn.sort(N())
        for i in range(N()):
            fn.neighbours_density(i)
        if ti.static(ext):
            wp.mark()  # the walls in reach of the liquid, and their hydrostatic k

    @ti.kernel
    def divergence_begin(dt: f):
        neighbours()
        solve_begin(dt, DIV, False)

    @ti.kernel
    def divergence_iteration(dt: f):
        iteration(dt, DIV)

    @ti.kernel
    def density_begin(dt: f, after_divergence: ti.template()):
        if ti.static(not after_divergence):
            neighbours()
        for i in range(N()):
            if ti.static(after_divergence):
                kappav[i] = kacc[i] * dt  # total divergence stiffness, dt independent
            a = fn.non_pressure(i, False)
            if ti.static(ext):
                a -= wp.wall_sum(i, wp.bhyd)  # the walls' hydrostatic pressure, once per substep
            if ti.static(ext_map):
                a -= Hb[i]  # the boundary's hydrostatic part, once per substep with gravity
            vnew[i] = v[i] + dt * a
        if ti.static(P.named_loads):  # no-slip viscosity's reaction on named colliders (moving.py)
            for i in range(N()):
                fn.load_viscous(i, dt)
        solve_begin(dt, DENS, True)  # v = vnew first

    @ti.kernel
    def density_iteration(dt: f):
        iteration(dt, DENS)

    @ti.func
    def named_loads(dt):
        if ti.static(P.named_loads):
            # the pressure solves' reaction on named colliders (moving.py): the substep's total stiffness K_i
            # (in kk, a scratch field until the next solve) and its Shepard average on the walls (bval)
            for i in range(N()):
                ktot = kacc[i]
                if ti.static(P.divergence_solve):
                    ktot += kappav[i] / dt
                kk[i] = ktot
            if ti.static(ext):
                wp.update(kk)
            for i in range(N()):
                fn.load_pressure(i, dt)

    @ti.func
    def pressure(i, dt):
        kappa[i] = kacc[i]  # an acceleration-level stiffness: steady under gravity for any dt
        r = rho[i]
        kdiv = ti.cast(0.0, f)
        if ti.static(P.divergence_solve):
            kdiv = kappav[i] / dt
        p[i] = (kacc[i] + kdiv) * r * r / mat_rho0[mid[i]]

    @ti.kernel
    def finish(dt: f):
        named_loads(dt)
        for i in range(N()):
            pressure(i, dt)
            fn.advect(i, v[i], dt)

    # coupled scenes (simcli/coupling/): finish in two halves around the coupling phase, which edits v
    @ti.kernel
    def finish_pressure(dt: f):
        named_loads(dt)
        for i in range(N()):
            pressure(i, dt)

    @ti.kernel
    def advect_all(dt: f):
        for i in range(N()):
            fn.advect(i, v[i], dt)

    def error() -> float:
        return float(err_acc[None]) / FIXED / max(1, n_live())

    def solves(dt: float) -> None:
        o = P
        if o.divergence_solve:
            divergence_begin(dt)
            eta = o.max_divergence_error_percent / 100.0
            it, err = 0, error()
            while (err > eta or it < 1) and it < o.max_divergence_iterations:
                divergence_iteration(dt)
                it += 1
                err = error()
            stats.add("divergence", it, err, it >= o.max_divergence_iterations and err > eta)
            density_begin(dt, True)
        else:
            density_begin(dt, False)
        eta = o.max_density_error_percent / 100.0
        it, err = 0, error()
        while (err > eta or it < 2) and it < o.max_density_iterations:
            density_iteration(dt)
            it += 1
            err = error()
        stats.add("density", it, err, it >= o.max_density_iterations and err > eta)

    def substep(dt: float) -> None:
        solves(dt)
        finish(dt)

    def pre_couple(dt: float) -> None:
        solves(dt)
        finish_pressure(dt)

    return substep, (pre_couple, advect_all, v)  # (pre, post, the velocity the coupling edits)


class SolveStats:
    """Iterations and final average errors of the DFSPH solves, per substep (host side)."""

    def __init__(self) -> None:
        self.d: dict[str, dict] = {}

    def add(self, solve: str, iterations: int, err: float, capped: bool) -> None:
        s = self.d.setdefault(
            solve,
            {
                "substeps": 0,
                "iterations": 0,
                "max_iterations": 0,
                "capped": 0,
                "max_error": 0.0,
                "sum_error": 0.0,
                "last_error": 0.0,
            },
        )
        s["substeps"] += 1
        s["iterations"] += iterations
        s["max_iterations"] = max(s["max_iterations"], iterations)
        s["capped"] += int(capped)
        if math.isfinite(err):
            s["max_error"] = max(s["max_error"], err)
            s["sum_error"] += err
        else:
            s["max_error"] = math.inf
        s["last_error"] = err

    def report(self) -> dict:
        out = {}
        for k, s in self.d.items():
            m = max(1, s["substeps"])
            out[k] = {
                "substeps": s["substeps"],
                "iterations_per_substep": round(s["iterations"] / m, 3),
                "max_iterations": s["max_iterations"],
                "substeps_at_cap": s["capped"],
                "average_error_percent_max": 100.0 * s["max_error"],
                "average_error_percent_mean": 100.0 * s["sum_error"] / m,
                "average_error_percent_last": 100.0 * s["last_error"],
            }
        return out
