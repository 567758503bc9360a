"""delta-SPH for WCSPH (``solvers.sph.density: continuity``, ``density_diffusion``, ``artificial_viscosity``).

* Continuity density (Monaghan 1992; Antuono et al. 2010, Marrone et al. 2011): each particle's density is a
  state, d rho_i / dt = rho_i sum_j V_j (v_i - v_j) . grad W_ij + rho_i sum_b V_b (v_i - v_b) . grad W_ib,
  V_j = m_j / rho_j; the wall part is rho_i (v_i . B_i - Sb_i) from the sums density.py keeps (boundary
  particles or volume maps, the walls' velocity included). Integrated as the substep's symplectic Euler:
  v^{n+1} from the pressure of rho^n, then rho^{n+1} = rho^n + dt D rho(x^n, v^{n+1}), x^{n+1} = x^n + dt
  v^{n+1} (the density follows the displacement the positions take).
* Density diffusion, added to d rho_i / dt: delta h c0 sum_j psi_ij . grad W_ij V_j (h = half the support
  radius, the smoothing length of a kernel of support 2 h; c0 = sqrt(k n / rho0)), liquid pairs only, with
  x_ij = x_i - x_j (with several liquids, pairs of one material only):

  - molteni_colagrossi (Molteni & Colagrossi 2009): psi_ij = 2 (rho_i - rho_j) x_ij / |x_ij|^2;
  - antuono (Antuono et al. 2010; Marrone et al. 2011): psi_ij minus (<grad rho>_i + <grad rho>_j), the
    renormalised gradient <grad rho>_i = L_i sum_j (rho_j - rho_i) grad W_ij V_j with L_i = (sum_j V_j grad
    W_ij (x_j - x_i)^T)^-1 (the identity where that matrix is deficient: determinant < 0.5, a free
    surface); zero for a linear density field, so a liquid at rest keeps its hydrostatic density;
  - fourtakis (Fourtakis et al. 2019; DualSPHysics' DDT 2): psi_ij = 2 ((rho_i - rho_j) - rho_ij^H) x_ij /
    |x_ij|^2 with rho_ij^H = rho0 ((1 + rho0 g . x_ij / k)^(1 / n) - 1), Tait's hydrostatic density
    difference: the diffusion acts on the dynamic density only.

* Artificial viscosity (Monaghan 1992, beta = 0): a_i = sum_j m_j alpha c0 h (v_ij . x_ij) / ((|x_ij|^2 +
  0.01 h^2) rho_ij) grad W_ij for approaching pairs (v_ij . x_ij < 0), rho_ij the pair's mean density.

TrixiParticles.jl (``DensityDiffusionMolteniColagrossi``, ``DensityDiffusionAntuono``,
``ArtificialViscosityMonaghan``) and DualSPHysics (``DDT``) implement the same terms; this module is
written from the papers' formulas.
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams

with stdout_to_stderr():
    import taichi as ti

# the renormalisation matrix of a full neighbourhood has determinant ~1 (a lattice); below this the
# gradient is left uncorrected (density.py's FULL_MOMENT choice for the kernel gradient correction)
MIN_DET = 0.5


def make_delta_sph(P: SPHParams, F: SPHFields, fn: SPHFuncs):
    """``(density_gradient, density_rate, artificial_viscosity)``, Taichi funcs of one particle:
    ``density_gradient(i)`` writes F.grad_rho[i] (antuono only); ``density_rate(i)`` writes F.drho[i] from
    the end-of-substep velocity F.vnew; ``artificial_viscosity(i)`` returns the acceleration."""
    dim, f = P.dim, P.f
    hs = 0.5 * P.h  # smoothing length
    eps = 0.01 * hs * hs
    gradW, mass_of = fn.gradW, fn.mass_of
    x, v, vnew, rho, mid = F.x, F.v, F.vnew, F.rho, F.mid
    nb_cnt, nb_j = F.nb_cnt, F.nb_j
    B, Sb = F.B, F.Sb
    drho, grho = F.drho, F.grad_rho
    mat_rho0, mat_k, mat_n, gravity = F.mat_rho0, F.mat_k, F.mat_n, F.gravity
    uniform = P.uniform
    model = P.diffusion_model
    diffuse = model != ""
    antuono = model == "antuono"
    fourtakis = model == "fourtakis"
    dh = float(P.diffusion_delta * hs)
    alpha_h = float(P.artificial_viscosity * hs)

    @ti.func
    def sound_speed(m):
        return ti.sqrt(mat_k[m] * mat_n[m] / mat_rho0[m])

    @ti.func
    def density_gradient(i):
        if ti.static(antuono):
            xi = x[i]
            ri = rho[i]
            G = ti.Vector.zero(f, dim)
            M = ti.Matrix.zero(f, dim, dim)  # sum_j V_j grad W_ij (x_j - x_i)^T
            for k in range(nb_cnt[i]):
                j = nb_j[i, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                d = xi - x[j]
                g = gradW(d, d.norm())
                Vj = mass_of(j) / rho[j]
                same = 1
                if ti.static(not uniform):
                    same = ti.cast(mid[j] == mid[i], ti.i32)
                if same != 0:
                    G += (rho[j] - ri) * Vj * g
                M -= (Vj * g).outer_product(d)
            if M.determinant() >= MIN_DET:
                G = M.inverse() @ G
            grho[i] = G

    @ti.func
    def density_rate(i):
        xi = x[i]
        vi = vnew[i]
        ri = rho[i]
        m = mid[i]
        cont = ti.cast(0.0, f)
        dif = ti.cast(0.0, f)
        rho0 = mat_rho0[m]
        k_eos = mat_k[m]
        inv_n = 1.0 / mat_n[m]
        gi = ti.Vector.zero(f, dim)
        if ti.static(antuono):
            gi = grho[i]
        gvec = gravity[None]
        for k in range(nb_cnt[i]):
            j = nb_j[i, k]
            if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                break
            d = xi - x[j]
            r2 = d.dot(d)
            g = gradW(d, ti.sqrt(r2))
            rj = rho[j]
            Vj = mass_of(j) / rj
            cont += Vj * (vi - vnew[j]).dot(g)
            if ti.static(diffuse):  # noqa: SIM102 - compile-time, then run-time test
                # several liquids: only pairs of one material (the density jump at an interface of two rest
                # densities is not noise)
                same = 1
                if ti.static(not uniform):
                    same = ti.cast(mid[j] == m, ti.i32)
                if r2 > 0 and same != 0:
                    dr = ri - rj
                    if ti.static(fourtakis):
                        # Tait's hydrostatic density difference of the pair (gravity along x_ij)
                        pH = rho0 * gvec.dot(d)
                        dr -= rho0 * (ti.pow(ti.max(1.0 + pH / k_eos, 1e-6), inv_n) - 1.0)
                    psi_g = 2.0 * dr * d.dot(g) / r2
                    if ti.static(antuono):
                        psi_g -= (gi + grho[j]).dot(g)
                    dif += Vj * psi_g
        # the walls (boundary particles or maps): rho_i sum_b V_b (v_i - v_b) . grad W_ib
        rate = ri * (cont + vi.dot(B[i]) - Sb[i])
        if ti.static(diffuse):
            rate += dh * sound_speed(m) * dif
        drho[i] = rate

    @ti.func
    def artificial_viscosity(i):
        a = ti.Vector.zero(f, dim)
        if ti.static(alpha_h > 0):
            xi, vi = x[i], v[i]
            ri = rho[i]
            ci = sound_speed(mid[i])
            for k in range(nb_cnt[i]):
                j = nb_j[i, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                d = xi - x[j]
                vr = (vi - v[j]).dot(d)
                if vr < 0:
                    r2 = d.dot(d)
                    g = gradW(d, ti.sqrt(r2))
                    cbar = 0.5 * (ci + sound_speed(mid[j]))
                    rbar = 0.5 * (ri + rho[j])
                    a += mass_of(j) * alpha_h * cbar * vr / ((r2 + eps) * rbar) * g
        return a

    return density_gradient, density_rate, artificial_viscosity
