"""neighbours -> density: one pass per particle over the cell stencil that builds its neighbour list (with
grad W_ij for DFSPH), sums its density (liquid and boundary particles, Akinci et al. 2012), and the boundary
sums later passes read (sum_b V_b grad W_ib, DFSPH's wall density rate, no-slip walls' viscous matrix), the
surface normal (surface tension), the shifting displacement, the kernel gradient correction L_i and DFSPH's
alpha_i (dfsph.py). Extrapolated walls (wall_pressure.py): the boundary neighbours are listed after the
liquid ones, and the boundary particles in reach are flagged."""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams
from simcli.solvers.sph.kernels import VISC_EPS, kernel_constant, make_kernel_factor

with stdout_to_stderr():
    import taichi as ti

# gradient_correction: scalar corrects particles whose moment matrix has a mean diagonal of at least this
# (a full neighbourhood; a lattice: 1.012 in 2D, 1.020 in 3D; the matrix correction's det >= 0.5, for an
# isotropic matrix)
FULL_MOMENT = 0.75


def make_neighbours_density(P: SPHParams, F: SPHFields, fn: SPHFuncs):
    """``neighbours_density(i)``, a Taichi func; needs the stencil and the smoothing kernels in ``fn``."""
    dim, f, K, R = P.dim, P.f, P.K, P.R
    h = P.h
    h2 = h * h
    eps_visc = VISC_EPS * h2
    W_gradW_s = make_kernel_factor(h, dim, f)
    store_grad = F.nb_s is not None  # DFSPH, and WCSPH on the CPU (solver.py)
    W0 = kernel_constant(h, dim)  # W(0)
    x, mid, rho = F.x, F.mid, F.rho
    nb_cnt, nbb_cnt, nb_j, nb_s, B, Sb = F.nb_cnt, F.nbb_cnt, F.nb_j, F.nb_s, F.B, F.Sb
    nrm, Mv, mw, alpha, shift = F.nrm, F.Mv, F.mw, F.alpha, F.shift
    has_shift = shift is not None
    shift_c = float(P.shifting * P.ps**2)
    shift_max = 0.1 * P.ps
    start, bstart, bx, bV, bvel, bns = F.start, F.bstart, F.bx, F.bV, F.bvel, F.bns
    bnear = F.bnear
    mat_rho0 = F.mat_rho0
    overflow = F.overflow
    has_tension, has_noslip = P.has_tension, P.has_noslip
    dfsph = alpha is not None
    kgc, Lm, Lc, kgc_scalar = P.kgc, F.Lm, F.Lc, P.kgc_scalar
    has_boundary = P.nbp > 0
    ext_walls, nbw_end, bflag = P.ext_walls and has_boundary, F.nbw_end, F.bflag
    linear = fn.linear
    rows, row_cell, mass_of, volume_of = fn.rows, fn.row_cell, fn.mass_of, fn.volume_of
    row = 2 * R + 1
    from simcli.solvers.sph.dfsph import BFAC as bfac

    if P.volume_map and F.Hb is not None:
        # volume maps' mirrored wall stiffness (dfsph.py): the boundary pushes with k_i + k_i, and the
        # diagonal says so (with 1 a DFSPH tank at rest kept 3-5 cm/s of noise and read -2.5% floor pressure)
        bfac = 2.0 * bfac

    uniform = P.uniform
    continuity = P.continuity
    vmap = P.volume_map
    Hb, gravity = F.Hb, F.gravity
    has_hb = Hb is not None

    @ti.func
    def neighbours_density(i):
        """neighbours -> density: neighbour list with grad W, density, and the boundary sums."""
        xi = x[i]
        c0 = rows(xi)
        rho0_i = mat_rho0[mid[i]]
        r_i = mass_of(i) * W0
        G = ti.Vector.zero(f, dim)
        sumsq = ti.cast(0.0, f)
        Mom = ti.Matrix.zero(f, dim, dim)  # sum_j V_j grad W_ij (x_j - x_i)^T (gradient correction)
        Mtr = ti.cast(0.0, f)  # its trace (gradient_correction: scalar)
        cnt = 0
        for a in range(row ** (dim - 1)):  # a run-time loop: unrolled, it compiles for minutes
            lin = row_cell(c0, a)
            for j in range(start[lin], start[lin + row]):
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                d = xi - x[j]
                r2 = d.dot(d)
                if r2 < h2 and j != i:
                    r = ti.sqrt(r2)
                    w, g, s = W_gradW_s(d, r)
                    Vg = volume_of(j) * g
                    if ti.static(uniform):
                        r_i += mass_of(j) * w
                        sumsq += Vg.dot(Vg)
                    else:
                        # number density rho0_i sum_j V_j W_ij (SPlisHSPlasH): continuous across an
                        # interface of two rest densities, where the mass sum gives the lighter liquid a
                        # false excess
                        r_i += rho0_i * volume_of(j) * w
                        # the pressure operator's diagonal with the momentum-conserving pair force
                        # (dfsph.py): V_j (m_i / rho0_j) |grad W_ij|^2
                        sumsq += (mass_of(i) / mat_rho0[mid[j]]) * Vg.dot(g)
                    if ti.static(kgc_scalar):
                        Mtr -= Vg.dot(d)
                    elif ti.static(kgc):
                        Mom -= Vg.outer_product(d)
                    if ti.static(dfsph):
                        G += Vg
                    else:  # (WCSPH needs no Vg: V_j s_ij (x_i - x_j), three multiplications fewer)
                        G += (volume_of(j) * s) * d
                    if cnt < K:
                        nb_j[i, cnt] = j
                        if ti.static(store_grad):
                            nb_s[i, cnt] = s  # grad W_ij = d s
                    cnt += 1
        if cnt > K:
            ti.atomic_add(overflow[None], cnt - K)
        nb_cnt[i] = ti.min(cnt, K)
        cnt_w = ti.min(cnt, K)  # extrapolated walls: the boundary neighbours' slots follow
        Bi = ti.Vector.zero(f, dim)
        Si = ti.cast(0.0, f)
        Qb = ti.Matrix.zero(f, dim, dim)  # sum_b V_b grad W_ib v_b^T: Si with the corrected gradient
        cntb = 0
        M = ti.Matrix.zero(f, dim, dim)
        m_w = ti.Vector.zero(f, dim)
        if ti.static(has_boundary):  # noqa: SIM102 - compile-time, then run-time test
            if bnear[linear(c0) + R] != 0:  # most particles have no boundary particle in reach
                for a in range(row ** (dim - 1)):
                    lin = row_cell(c0, a)
                    for b in range(bstart[lin], bstart[lin + row]):
                        if b < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                            break
                        d = xi - bx[b]
                        r2 = d.dot(d)
                        if r2 < h2:
                            r = ti.sqrt(r2)
                            Vb = bV[b]
                            w, g, s = W_gradW_s(d, r)
                            r_i += rho0_i * Vb * w
                            Bi += Vb * g
                            if ti.static(ext_walls):
                                bflag[b] = 1  # the same value from every writer
                                if cnt_w < K:
                                    nb_j[i, cnt_w] = b
                                    if ti.static(store_grad):
                                        nb_s[i, cnt_w] = s  # V_b grad W_ib = V_b (d s)
                                cnt_w += 1
                            Si += Vb * bvel[b].dot(g)
                            if ti.static(kgc_scalar):
                                Mtr -= Vb * g.dot(d)
                            elif ti.static(kgc):
                                Mom -= (Vb * g).outer_product(d)
                                Qb += (Vb * g).outer_product(bvel[b])
                            cntb += 1
                            if ti.static(has_noslip):  # noqa: SIM102 - compile-time, then run-time test
                                if bns[b] != 0:
                                    coef = Vb / (r2 + eps_visc)
                                    M += coef * g.outer_product(d)
                                    m_w += coef * bvel[b].dot(d) * g
        if ti.static(vmap):  # walls and static colliders as precomputed maps (volume_map.py)
            psi, Bm, cm, Tm, Mm, mwm, Sm, Hy, Mb, Qm = fn.boundary_map(xi, gravity[None], i)
            if ti.static(has_hb):
                Hb[i] = Hy
            r_i += rho0_i * psi
            Bi += Bm
            Si += Sm
            cntb += ti.cast(cm + 0.5, ti.i32)
            if ti.static(kgc_scalar):
                Mtr += Tm
            elif ti.static(kgc):
                # the map's moment sum_b V_b grad W_ib (x_i - x_b)^T and its B v^T (volume_map.py)
                Mom -= Mb
                Qb += Qm
            if ti.static(has_noslip):
                M += Mm
                m_w += mwm
        if ti.static(not continuity):  # density: continuity keeps rho as a state (delta_sph.py)
            rho[i] = r_i
        if ti.static(kgc_scalar):  # the isotropic part only: L_i = (dim / trace) I
            ci = ti.cast(1.0, f)
            if Mtr >= dim * FULL_MOMENT:  # a full neighbourhood (a lattice: 1.01-1.02)
                ci = dim / Mtr
            Lc[i] = ci
            Si *= ci  # sum_b V_b v_b . c_i grad W_ib
        elif ti.static(kgc):
            Li = ti.Matrix.identity(f, dim)
            if Mom.determinant() >= 0.5:  # a full neighbourhood (a lattice: 1)
                Li = Mom.inverse()
            Lm[i] = Li
            Si = (Li @ Qb).trace()  # sum_b V_b v_b . L_i grad W_ib
        B[i] = Bi
        if ti.static(ext_walls):
            if cnt_w > K:
                ti.atomic_add(overflow[None], cnt_w - K)
            nbw_end[i] = ti.min(cnt_w, K)
        Sb[i] = Si
        nbb_cnt[i] = cntb
        if ti.static(has_noslip):
            Mv[i] = M
            mw[i] = m_w
        if ti.static(has_tension):
            nrm[i] = h * G  # surface normal of Akinci et al. 2013 (eq. 4), fluid part only
        if ti.static(has_shift):
            # particle shifting (Lind et al. 2012): down the concentration gradient grad C = sum_j V_j
            # grad W_ij + sum_b V_b grad W_ib, none in the deficient support of a free surface
            ds = ti.Vector.zero(f, dim)
            if r_i > 0.95 * rho0_i:
                ds = -shift_c * (G + Bi)
                ln = ds.norm()
                if ln > shift_max:
                    ds *= shift_max / ln
            shift[i] = ds
        if ti.static(dfsph):
            # diagonal of the pressure operator as the solve applies it: own velocity change
            # -dt k_i (G + bfac B) against the density rate's (G + B), plus the neighbours' reaction
            Gt = G + Bi
            den = ti.max((G + bfac * Bi).dot(Gt), 0.0) + sumsq
            if ti.static(kgc_scalar):
                # the solve applies c_i grad W in the velocity update and in the density rate: its diagonal
                # is c_i^2 times the uncorrected one (c_i up to 1 / FULL_MOMENT = 1.33 in a partial
                # neighbourhood, where the Jacobi step without it was up to 1.78x the intended)
                den *= Lc[i] * Lc[i]
            alpha[i] = 1.0 / den if den > 1e-9 else 0.0

    return neighbours_density
