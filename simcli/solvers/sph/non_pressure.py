"""non_pressure: gravity, viscosity and surface tension [m/s^2] of one particle, in one pass over its
neighbour list; WCSPH adds its symmetric pressure force in the same pass (wcsph.py).

* Viscosity: physical mu, Monaghan's (2005) Laplacian (or Morris et al. 1997: ``viscosity_operator:
  morris``), also against no-slip boundary particles (the matrix density.py summed);
* surface tension: Akinci et al. 2013, cohesion kernel + curvature from the surface normals, with the
  symmetric correction factor 2 rho0 / (rho_i + rho_j);
* several materials: symmetric pair coefficients (momentum-conserving), equal to the one-material terms
  for equal materials.
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams
from simcli.solvers.sph.kernels import VISC_EPS, make_cohesion_over_r, morris_laplacian_constant

with stdout_to_stderr():
    import taichi as ti


def make_non_pressure(P: SPHParams, F: SPHFields, fn: SPHFuncs):
    """``non_pressure(i, with_pressure)``, a Taichi func; needs the smoothing kernels and ``fn.mass_of``."""
    dim, f = P.dim, P.f
    h = P.h
    h2 = h * h
    eps_visc = VISC_EPS * h2
    gradW = fn.gradW
    C_over_r = make_cohesion_over_r(h, f)  # Akinci's C(r) / r without the division (kernels.py)
    store_grad = F.nb_s is not None  # the list keeps grad W's factor (DFSPH; WCSPH on the CPU)
    x, v, mid, rho = F.x, F.v, F.mid, F.rho
    nb_cnt, nb_j, nb_s = F.nb_cnt, F.nb_j, F.nb_s
    nrm, Mv, mw = F.nrm, F.Mv, F.mw
    mat_rho0, mat_nu, mat_gamma, gravity = F.mat_rho0, F.mat_nu, F.mat_gamma, F.gravity
    has_tension, has_noslip, has_visc = P.has_tension, P.has_noslip, P.has_viscosity
    visc_c = 2.0 * (dim + 2)
    morris = P.viscosity_operator == "morris"
    morris_c = morris_laplacian_constant(h / P.ps, dim)
    uniform = P.uniform
    mass_of = fn.mass_of
    p = F.p
    pr2 = F.pr2
    has_pr2 = pr2 is not None
    m_rho = F.m_rho  # WCSPH, one material: m_j / rho_j per particle, written with the pressure (wcsph.py)
    has_m_rho = m_rho is not None

    # WCSPH's force pass with one material, Monaghan's viscosity and the list's gradient factor (C1's water):
    # every pair term but the curvature's is a number times x_i - x_j (grad W_ij = (x_i - x_j) s_ij), so the
    # pair loop sums one coefficient per pair and one vector, with the material constants (2 (dim + 2) nu,
    # gamma) inside; the same forces as the general loop below to round-off (a sum in another grouping)
    fused = uniform and store_grad and has_pr2 and not morris and (has_m_rho or not has_visc)

    @ti.func
    def fused_pairs(i):
        """non_pressure(i, True) for the one-material WCSPH case above."""
        xi, vi = x[i], v[i]
        m = mid[i]
        nu_c = visc_c * mat_nu[m]
        gam = mat_gamma[m]
        rho0 = mat_rho0[m]
        ri = rho[i]
        dpi = p[i] / (ri * ri)
        mj = mass_of(i)  # one material: the particles' constant mass
        ni = ti.Vector.zero(f, dim)
        if ti.static(has_tension):
            ni = nrm[i]
        acc = ti.Vector.zero(f, dim)  # sum_j c_ij (x_i - x_j)
        an = ti.Vector.zero(f, dim)  # the curvature term, sum_j k_ij (n_i - n_j)
        for k in range(nb_cnt[i]):
            j = nb_j[i, k]
            if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                break
            d = xi - x[j]
            s = nb_s[i, k]
            c = -mj * (dpi + pr2[j]) * s  # the pressure force, -m_j (p_i / rho_i^2 + p_j / rho_j^2) grad W
            if ti.static(has_visc or has_tension):
                r2 = d.dot(d)
                if ti.static(has_visc):  # Monaghan's Laplacian, m_j / rho_j v_ij . x_ij / (r^2 + eps) grad W
                    c += nu_c * m_rho[j] * (vi - v[j]).dot(d) * s / (r2 + eps_visc)
                if ti.static(has_tension):  # noqa: SIM102 - compile-time, then run-time test
                    if r2 > 0:  # Akinci et al. 2013: cohesion and curvature, 2 rho0 / (rho_i + rho_j)
                        kij = 2.0 * rho0 / (ri + rho[j])
                        c -= gam * kij * mj * C_over_r(ti.sqrt(r2))
                        an -= kij * (ni - nrm[j])
            acc += c * d
        a = gravity[None] + acc
        if ti.static(has_tension):
            a += gam * an
        if ti.static(has_noslip):
            a += nu_c * (Mv[i] @ vi - mw[i])
        return a

    @ti.func
    def non_pressure(i, with_pressure: ti.template()):
        """gravity + viscosity + surface tension [m/s^2]; with_pressure: plus WCSPH's symmetric pressure
        force, -sum_j m_j (p_i / rho_i^2 + p_j / rho_j^2) grad W_ij, in the same pass over the
        neighbours."""
        a = gravity[None]
        if ti.static(fused and with_pressure):
            a = fused_pairs(i)
        elif ti.static(has_visc or has_tension or with_pressure):
            xi, vi = x[i], v[i]
            m = mid[i]
            nu = mat_nu[m]
            gam = mat_gamma[m]
            rho0 = mat_rho0[m]
            ri = rho[i]
            dpi = ti.cast(0.0, f)
            if ti.static(with_pressure):
                dpi = p[i] / (ri * ri)
            av = ti.Vector.zero(f, dim)
            avm = ti.Vector.zero(f, dim)  # Morris et al. 1997 sum (viscosity_operator: morris)
            at = ti.Vector.zero(f, dim)
            ap = ti.Vector.zero(f, dim)
            ni = ti.Vector.zero(f, dim)
            if ti.static(has_tension):
                ni = nrm[i]
            for k in range(nb_cnt[i]):
                j = nb_j[i, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                d = ti.Vector.zero(f, dim)
                r2 = ti.cast(0.0, f)
                if ti.static(has_visc or has_tension or not store_grad):
                    d = xi - x[j]
                    r2 = d.dot(d)
                g = ti.Vector.zero(f, dim)
                if ti.static(store_grad):
                    g = (xi - x[j]) * nb_s[i, k]  # the list's factor: grad W_ij (d when computed above)
                else:
                    g = gradW(d, ti.sqrt(r2))
                rj = rho[j]
                mj = mass_of(j)
                if ti.static(with_pressure):
                    if ti.static(uniform and has_pr2):
                        ap -= mj * (dpi + pr2[j]) * g  # p_j / rho_j^2, written with the pressure
                    elif ti.static(uniform):
                        ap -= mj * (dpi + p[j] / (rj * rj)) * g
                    else:
                        # several materials: Solenthaler & Pajarola's (2008) density-contrast form,
                        # -(1 / m_i) sum_j (p_i / delta_i^2 + p_j / delta_j^2) grad W with delta = rho /
                        # m, a consistent -grad p / rho_i across an interface (m_j p_j / rho_j^2 weighted
                        # the lighter liquid's pressure by rho_i / rho_j there); the same for one material
                        mi = mass_of(i)
                        ap -= (mi * dpi + (mj * mj / mi) * p[j] / (rj * rj)) * g
                if ti.static(has_visc or has_tension):
                    if ti.static(has_visc):
                        vis = ti.cast(0.0, f)
                        if ti.static(uniform and has_m_rho):
                            vis = m_rho[j]  # m_j / rho_j, once per particle instead of per pair
                        else:
                            vis = mj / rj  # one material: times nu_i below
                        if ti.static(not uniform):
                            # several materials: the pair's mean dynamic viscosity over rho_i rho_j,
                            # symmetric in i and j so that momentum is conserved (Morris et al. 1997)
                            vis *= 0.5 * (nu * rho0 + mat_nu[mid[j]] * mat_rho0[mid[j]]) / ri
                        if ti.static(morris):
                            avm += vis * (d.dot(g) / (r2 + eps_visc)) * (vi - v[j])
                        else:
                            av += vis * (vi - v[j]).dot(d) / (r2 + eps_visc) * g
                    if ti.static(has_tension):  # noqa: SIM102 - compile-time, then run-time test
                        if r2 > 0:
                            r = ti.sqrt(r2)
                            if ti.static(uniform):
                                kij = 2.0 * rho0 / (ri + rj)
                                at -= kij * (mj * C_over_r(r) * d + (ni - nrm[j]))
                            else:
                                # several materials: Akinci's pair term with symmetric coefficients (the
                                # pair's mean gamma, (rho0_i + rho0_j) / (rho_i + rho_j), the curvature
                                # term weighted 2 m_j / (m_i + m_j)), so that momentum is conserved; equal
                                # to Akinci's for equal materials
                                mi = mass_of(i)
                                kij = (
                                    (0.5 * (gam + mat_gamma[mid[j]])) * (rho0 + mat_rho0[mid[j]]) / (ri + rj)
                                )
                                at -= kij * (mj * C_over_r(r) * d + (2.0 * mj / (mi + mj)) * (ni - nrm[j]))
            if ti.static(uniform):
                if ti.static(has_noslip):
                    av += Mv[i] @ vi - mw[i]
                a += visc_c * nu * av + gam * at + ap
                if ti.static(morris):
                    a += morris_c * nu * avm
            else:
                # the pair coefficients are inside av, avm and at; the walls' viscosity is the liquid's
                # own
                if ti.static(has_noslip):
                    a += visc_c * nu * (Mv[i] @ vi - mw[i])
                a += visc_c * av + at + ap
                if ti.static(morris):
                    a += morris_c * avm
        return a

    return non_pressure
