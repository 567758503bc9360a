"""WCSPH (Becker & Teschner 2007): Tait equation of state and the symmetric pressure force, one kernel
launch per substep::

    neighbours -> density (+ equation of state) -> non_pressure + pressure -> advect

Pressure: p_i = k ((rho_i / rho0)^n - 1) (+ background pressure), clamped at zero for a free surface.
Force (momentum-conserving, symmetric): a_i = -sum_j m_j (p_i / rho_i^2 + p_j / rho_j^2) grad W_ij, and from
boundary particles (Akinci et al. 2012, eq. 10) a_i = -sum_b rho0 V_b (p_i / rho_i^2) grad W_ib, plus with
``wall_pressure: extrapolated`` (the default with a free surface since session 8) the walls' own pressure,
-sum_b rho0 V_b (p_b / rho_b^2) grad W_ib, p_b relaxing towards Adami et al.'s (2012) extrapolation from the
liquid (wall_pressure.py: why it relaxes). (Full pressure mirroring, 2 p_i / rho_i^2, balances a uniform
pressure exactly at a wall, but made a tank at rest with water's viscosity unstable in our tests; so did
the extrapolation taken at once: both are non-conservative forces that pump the acoustic noise. Akinci's
single term alone is stable, and leaves the wall layer at 1.7x the hydrostatic pressure.)
Time integration: symplectic Euler (v, then x with the new v).
``density: continuity`` (delta_sph.py): rho is a state, integrated after the velocity (rho^{n+1} from
v^{n+1}), with ``density_diffusion`` and ``artificial_viscosity`` the delta-SPH terms; the summation
density is not written then (density.py).
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams

with stdout_to_stderr():
    import taichi as ti


# density: continuity with clamp_pressure: the continuity density's floor [rho0]
CONTINUITY_FLOOR = 0.5


def make_tait_power(n_int: int, f, mat_n):
    """Taichi func ``tait_power(ratio, m) = ratio^n`` of Tait's equation: for a whole exponent known at build
    (``n_int`` > 0; SPHParams.int_exponent) by squaring (7: four multiplications, a fifth of pow's time on
    the CPU), else ``pow(ratio, mat_n[m])``; the same to round-off (tests/unit/test_sph_kernels.py)."""

    @ti.func
    def tait_power(ratio, m):
        res = ti.cast(1.0, f)
        if ti.static(n_int > 0):
            b = ratio
            for k in ti.static(range(n_int.bit_length())):
                if ti.static((n_int >> k) & 1):
                    res = res * b
                if ti.static(k + 1 < n_int.bit_length()):
                    b = b * b
        else:
            res = ti.pow(ratio, mat_n[m])
        return res

    return tait_power


def make_wcsph(P: SPHParams, F: SPHFields, fn: SPHFuncs):
    """WCSPH's kernels: ``(substep, pressure_from_density, couple_phases)``. ``substep(dt)`` is the whole
    substep; ``pressure_from_density()`` sets the pressure from the current density (the output before the
    first substep); ``couple_phases`` is ``(pre_couple, post_couple, vnew)``, the substep in two halves
    around a coupling phase and the velocity it edits. Needs every shared func in ``fn`` (density.py,
    non_pressure.py, advect.py; wall_pressure.py, moving.py where the scene has them)."""
    f = P.f
    rho, p, mid, v, vnew = F.rho, F.p, F.mid, F.v, F.vnew
    B = F.B
    mat_rho0, mat_k, mat_n = F.mat_rho0, F.mat_k, F.mat_n
    clamp = P.clamp_pressure
    p_bg = float(P.background_pressure)
    N = fn.count  # the active count (emitters, sinks) or the constant n
    # delta-SPH (delta_sph.py): the density as a state of the continuity equation, its diffusion and
    # Monaghan's artificial viscosity; compiled only when a scene asks for them
    continuity = P.continuity
    antuono = P.diffusion_model == "antuono"
    art_visc = P.artificial_viscosity > 0
    density_gradient = density_rate = artificial_viscosity = None
    if continuity or art_visc:
        from simcli.solvers.sph.delta_sph import make_delta_sph

        density_gradient, density_rate, artificial_viscosity = make_delta_sph(P, F, fn)
    drho = F.drho
    pr2 = F.pr2
    has_pr2 = pr2 is not None
    m_rho = F.m_rho
    has_m_rho = m_rho is not None
    mass_of = fn.mass_of

    tait_power = make_tait_power(int(P.int_exponent), f, mat_n)

    @ti.func
    def equation_of_state(i):
        m = mid[i]
        ratio = rho[i] / mat_rho0[m]
        pi = mat_k[m] * (tait_power(ratio, m) - 1.0)
        if ti.static(clamp):
            pi = ti.max(pi, 0.0)
        p[i] = pi + p_bg
        if ti.static(has_pr2):
            pr2[i] = p[i] / (rho[i] * rho[i])  # the force pass's p_j / rho_j^2 (non_pressure.py)
        if ti.static(has_m_rho):
            m_rho[i] = mass_of(i) / rho[i]  # ... and its viscosity's m_j / rho_j

    wp = fn.wall_pressure  # extrapolated wall pressure (wall_pressure.py), or None: Akinci's term alone
    ext = wp is not None

    # volume maps with the extrapolated wall pressure (volume_map.py): the boundary's pressure seen by
    # particle i is its own mirrored, relaxing towards p_i as the boundary particles' does towards the
    # extrapolation (wall_pressure.py: why it relaxes), plus the hydrostatic difference F.Hb
    Hb, pw = F.Hb, F.pw
    ext_map = pw is not None
    tau = float(P.wall_pressure_relaxation)

    @ti.func
    def boundary_pressure_acceleration(i, dt):
        ri = rho[i]
        m = mid[i]
        rho0 = mat_rho0[m]
        a = -rho0 * (p[i] / (ri * ri)) * B[i]  # Akinci et al. 2012, eq. 10
        if ti.static(ext):
            a += wp.wcsph_wall_force(i)  # the walls' own pressure (Adami et al. 2012)
        if ti.static(ext_map):
            pb = pw[i] + dt / (tau + dt) * (p[i] - pw[i])
            pw[i] = pb
            rb = rho0 * ti.pow(ti.max(pb, 0.0) / mat_k[m] + 1.0, 1.0 / mat_n[m])
            a -= (rho0 / (rb * rb)) * (pb * B[i] + rho0 * Hb[i])
        return a

    @ti.kernel
    def pressure_from_density():
        """Tait's pressure of the current density: frame 0's pressure, before the first substep
        computes it."""
        for i in range(N()):
            equation_of_state(i)

    @ti.func
    def forces(dt):
        if ti.static(P.moving_boundary):
            fn.move_boundary()  # moving colliders' boundary particles to this substep's pose (moving.py)
        fn.sort(N())
        for i in range(N()):
            fn.neighbours_density(i)
            equation_of_state(i)
        if ti.static(ext):
            wp.mark()  # the walls in reach of the liquid and their hydrostatic part
            wp.wcsph_pressure(dt)
        if ti.static(antuono):  # the renormalised density gradients, before the pairs read them
            for i in range(N()):
                density_gradient(i)
        for i in range(N()):
            # non_pressure and the liquid's pressure force in one pass over the neighbour list
            a = fn.non_pressure(i, True) + boundary_pressure_acceleration(i, dt)
            if ti.static(art_visc):
                a += artificial_viscosity(i)
            vnew[i] = v[i] + dt * a
        if ti.static(P.named_loads):  # the reaction on named colliders (moving.py), from the same state
            for i in range(N()):
                fn.load_pressure(i, dt)
                fn.load_viscous(i, dt)

    @ti.func
    def advect_all(dt):
        if ti.static(continuity):
            # d rho / dt from x^n and the end-of-substep velocity (after a coupling phase edited it), then
            # rho^{n+1}: the density follows the displacement the positions take below
            for i in range(N()):
                density_rate(i)
            for i in range(N()):
                r = rho[i] + dt * drho[i]
                if ti.static(clamp):
                    # with the pressure clamp nothing restores the density of a stretching jet: it ran down
                    # until the run went NaN (Buchner's dam break, H / 80, 0.7-0.87 s). A guard far below the
                    # acoustic swings: a floor at rho0 instead ratcheted the impact's rarefactions into
                    # pressure (docs/VALIDATION.md, delta-SPH)
                    r = ti.max(r, CONTINUITY_FLOOR * mat_rho0[mid[i]])
                rho[i] = r
        for i in range(N()):
            fn.advect(i, vnew[i], dt)

    @ti.kernel
    def substep(dt: f):
        forces(dt)
        advect_all(dt)

    # coupled scenes (simcli/coupling/): the same substep in two halves around the coupling phase, which edits
    # vnew (the velocity at the substep's end) before advect
    @ti.kernel
    def pre_couple(dt: f):
        forces(dt)

    @ti.kernel
    def post_couple(dt: f):
        advect_all(dt)

    return substep, pressure_from_density, (pre_couple, post_couple, vnew)
