"""Extrapolated wall pressure (``solvers.sph.wall_pressure: extrapolated``, the default for DFSPH with a free
surface and for WCSPH, ``auto``): each boundary particle
near the liquid gets a pressure of its own, the Shepard average of its liquid neighbours' pressures plus the
hydrostatic difference between them and it (Adami et al. 2012, "A generalized wall boundary condition for
smoothed particle hydrodynamics", eq. 27; for DFSPH as Band et al. 2018, "MLS pressure extrapolation for the
boundary handling in divergence-free SPH", with a Shepard instead of an MLS fit). In DFSPH's stiffness
k = p / rho0::

    k_b = sum_f k_f W_bf / sum_f W_bf  +  max(0, sum_f g . (x_b - x_f) W_bf / sum_f W_bf)

and the liquid feels it through the symmetric pressure force, dv_i = -dt sum_b V_b (k_i + k_b) grad W_ib,
instead of Akinci et al.'s (2012) -dt sum_b V_b k_i grad W_ib alone. (The hydrostatic part is clamped so that
a wall above the liquid never pulls.)

Why: with Akinci's term the layer of liquid next to a wall is pushed off it by its own pressure once, where
the liquid on the other side pushes with p_i + p_j; at rest that layer squeezes towards the wall until its
density, and so its pressure, is high enough: the particles next to a wall carry 1.7x the hydrostatic
pressure (2.15x in corners), and the start-up squeeze disorders a column at rest (docs/SPH.md). With the
extrapolated pressure a lattice at rest is in balance at the wall (the hydrostatic term supplies the
support of the missing liquid below).

The Shepard part is linear in the liquid's k, so each Jacobi iteration moves a boundary particle's k by the
average of that iteration's increments; the hydrostatic part is a fixed term of the substep, applied once
with gravity. Not for DFSPH's conjugate-gradient solve (clamp_pressure: false), whose operator must stay
symmetric.

WCSPH (since session 8): the same extrapolation in pressure (Adami et al. 2012, eq. 27, static walls),
p_b* = sum_f p_f W_bf / sum_f W_bf + max(0, rho0 sum_f g . (x_b - x_f) W_bf / sum_f W_bf), the boundary
particle's density from the inverse of Tait's equation, rho_b = rho0 (p_b / k + 1)^(1/n), and the symmetric
pressure force -rho0 V_b (p_i / rho_i^2 + p_b / rho_b^2) grad W_ib. What makes it stable: p_b does not follow
p_b* at once but relaxes towards it, p_b += dt / (tau + dt) (p_b* - p_b) each substep
(``wall_pressure_relaxation`` tau, 0.2 s; a boundary particle that no liquid reached in the last substep
starts at p_b*). With p_b following the liquid's pressure at once, the wall force on particle i depends on its
neighbours' pressures: a non-conservative force (no potential energy has it as its gradient), which on a
tank at rest pumped energy into the acoustic noise (5-9 cm/s, the wall layer thrown off: measured; so did the
mirror p_b = p_i). Against a p_b that changes slowly compared with the sound's periods, each liquid particle
moves in a nearly fixed potential sum_b (p_b / rho_b^2) rho0 V_b W_ib, which conserves energy; what is left of
the pumping is the lag's, which falls as 1 / (omega tau) for a sound wave of frequency omega, and the
viscosity removes it (tau 0.01 s: 5.6 cm/s; 0.05 s: 0.9-1.8 cm/s; 0.2 s: 0.52 cm/s, Akinci's 0.51). At rest
p_b reaches p_b* (the wall layer then in balance, as in DFSPH); in a fast change the wall pushes with the
particle's own pressure (Akinci's term) and the lagging part.

Lists are built once per substep: each liquid particle's boundary neighbours (with V_b grad W_ib) follow its
liquid ones in its neighbour list, and each boundary particle in reach of the liquid (``mark``) lists its
liquid neighbours with their Shepard weights; the iterations only walk these lists. Every value is a gather
in a fixed order: bitwise reproducible at any thread count.
"""

from types import SimpleNamespace

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams

with stdout_to_stderr():
    import taichi as ti


def make_wall_pressure(P: SPHParams, F: SPHFields, fn: SPHFuncs, bodies: tuple = ()):
    """Fields and Taichi funcs of the extrapolated wall pressure (a namespace: ``mark``, ``update``,
    ``wall_sum`` for DFSPH, ``wcsph_pressure``, ``wcsph_wall_force`` for WCSPH, and the fields ``bval``,
    ``bhyd``, ``pbar``, ``bq``); needs the stencil and the smoothing kernels in ``fn``. Only for a scene
    with boundary particles (``P.nbp > 0``).

    ``bodies``: the collider indices of free rigid bodies, whose boundary particles (and a deformable body's
    samples, ``F.bsrc``, deformable.py) take Adami's hydrostatic
    term unclamped where they are above the liquid (their total pressure kept >= 0: WCSPH by its clamp,
    DFSPH by the liquid's last total stiffness), see :func:`mark`."""
    f, dim = P.f, P.dim
    nbp = P.nbp
    R = P.R
    row = 2 * R + 1
    KB = max(
        8, P.K // 2
    )  # liquid neighbours listed per boundary particle: a half neighbourhood at rest is K / 4
    x = F.x
    bx, bV, start = F.bx, F.bV, F.start
    nb_cnt, nb_j, nb_s, nbw_end = F.nb_cnt, F.nb_j, F.nb_s, F.nbw_end
    Wk, h2 = fn.Wk, P.h2
    gravity, rows, row_cell, overflow = F.gravity, fn.rows, fn.row_cell, F.overflow
    bflag = F.bflag
    # several materials: the walls carry a pressure, the Shepard average of rho0_f k_f (plus rho0_f g . (x_b -
    # x_f)), which liquid particle i feels as the stiffness p_b / rho0_i; with one material simply the average
    # of k_f
    uniform, mat_rho0, mid = P.uniform, F.mat_rho0, F.mid

    bval = ti.field(f, shape=nbp)  # the boundary particle's k increment of the current iteration
    bhyd = ti.field(f, shape=nbp)  # its hydrostatic k of the substep
    active = ti.field(ti.i32, shape=nbp)  # boundary particles with liquid in reach, this substep
    n_active = ti.field(ti.i32, shape=())
    bnb_cnt = ti.field(
        ti.i32, shape=nbp
    )  # each one's liquid neighbours and Shepard weights W_bf / sum_f W_bf
    bnb_j = ti.field(ti.i32, shape=(nbp, KB))
    bnb_w = ti.field(f, shape=(nbp, KB))

    TAU = float(P.wall_pressure_relaxation)
    filt = not P.store_grad  # WCSPH: the walls' pressure relaxes towards the extrapolation (wcsph_pressure)
    pbar = ti.field(f, shape=nbp) if filt else None
    NEW = -1.0e30  # pbar of a boundary particle that no liquid reached in the last substep
    clamp = P.clamp_pressure
    bodies = tuple(bodies) if F.bcol is not None else ()
    bcol, kappa, dfsph = F.bcol, F.kappa, P.pressure_solver == "DFSPH"
    bsrc = F.bsrc  # a deformable body's samples take the free bodies' rule too
    has_src = bsrc is not None
    if filt:
        pbar.fill(NEW)

    @ti.func
    def mark():
        """After the neighbour search: list the boundary particles with liquid in reach, each one's liquid
        neighbours with their Shepard weights, and its hydrostatic k, sum_f g . (x_b - x_f) W_bf / sum_f W_bf,
        clamped at 0 (no pull where a wall is above the liquid).

        A free rigid body's boundary particles (``bodies``) take it unclamped (Adami et al.'s value), bounded
        below by minus the Shepard average of the liquid's stiffness (DFSPH: its last density solve's total;
        WCSPH clamps the sum itself), so that their total stays >= 0. The clamp gave the face of a body above
        the liquid (its bottom) the liquid's pressure at the depth of its neighbours, not at its own height:
        it pushed by rho g dz too much, the liquid stood off the body and the force on a held cube was
        rho g d A +5-6% (3D, particle 0.01 m, d 0.03 m; docs/RIGID.md)."""
        n_active[None] = 0
        for b in range(nbp):
            if bflag[b] == 0:  # no liquid particle reached it in this substep's neighbour search
                if ti.static(filt):
                    pbar[b] = NEW
                continue
            bflag[b] = 0
            xb = bx[b]
            c0 = rows(xb)
            sw = ti.cast(0.0, f)
            sh = ti.cast(0.0, f)
            cnt = 0
            for a in range(row ** (dim - 1)):
                lin = row_cell(c0, a)
                for j in range(start[lin], start[lin + row]):
                    if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                        break
                    d = xb - x[j]
                    r2 = d.dot(d)
                    if r2 < h2:
                        w = Wk(ti.sqrt(r2))
                        sw += w
                        if ti.static(uniform):
                            sh += w * gravity[None].dot(d)
                        else:
                            sh += w * mat_rho0[mid[j]] * gravity[None].dot(d)
                        if cnt < KB:
                            bnb_j[b, cnt] = j
                            bnb_w[b, cnt] = w
                        cnt += 1
            if cnt > KB:
                ti.atomic_add(overflow[None], cnt - KB)
            cnt = ti.min(cnt, KB)
            bnb_cnt[b] = cnt
            if sw > 0:
                active[ti.atomic_add(n_active[None], 1)] = b
                for k in range(cnt):
                    bnb_w[b, k] /= sw
                lim = ti.cast(0.0, f)
                if ti.static(len(bodies) > 0 or has_src):
                    body = False
                    if ti.static(len(bodies) > 0):
                        kb = bcol[b]
                        for q in ti.static(bodies):
                            if kb == q:
                                body = True
                    if ti.static(has_src):  # a deformable body's sample (deformable.py)
                        if bsrc[b] >= 0:
                            body = True
                    if body:
                        lim = ti.cast(-1.0e30, f)
                        if ti.static(dfsph):
                            lim = ti.cast(0.0, f)
                            for k in range(cnt):
                                if ti.static(uniform):
                                    lim -= bnb_w[b, k] * kappa[bnb_j[b, k]]
                                else:
                                    lim -= bnb_w[b, k] * mat_rho0[mid[bnb_j[b, k]]] * kappa[bnb_j[b, k]]
                bhyd[b] = ti.max(sh / sw, lim)

    @ti.func
    def update(src: ti.template()):
        """bval = the Shepard average of src over each listed boundary particle's liquid neighbours (the k
        increment of an iteration; linear, so the sum over the iterations is the average of the sum)."""
        for t in range(n_active[None]):
            b = active[t]
            acc = ti.cast(0.0, f)
            for k in range(bnb_cnt[b]):
                j = bnb_j[b, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                if ti.static(uniform):
                    acc += bnb_w[b, k] * src[j]
                else:
                    acc += bnb_w[b, k] * mat_rho0[mid[j]] * src[j]
            bval[b] = acc

    @ti.func
    def wall_sum(i, val: ti.template()):
        """sum_b V_b val_b grad W_ib over liquid particle i's boundary neighbours (listed after its liquid
        ones, with V_b grad W_ib)."""
        out = ti.Vector.zero(f, dim)
        xi = x[i]
        for k in range(nb_cnt[i], nbw_end[i]):
            b = nb_j[i, k]
            if b < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                break
            out += val[b] * (bV[b] * ((xi - bx[b]) * nb_s[i, k]))  # the list's factor: V_b grad W_ib
        if ti.static(not uniform):
            out /= mat_rho0[mid[i]]
        return out

    mat_k, mat_n = F.mat_k, F.mat_n
    bq = ti.field(f, shape=nbp) if not P.store_grad else None  # WCSPH: p_b / rho_b^2 (one material)
    p_liq = F.p
    list_s = nb_s is not None  # WCSPH on the CPU keeps grad W's factor in the list too (solver.py)
    gradW, bV = fn.gradW, F.bV

    @ti.func
    def wcsph_pressure(dt):
        """WCSPH (Adami et al. 2012, eq. 27, static walls): each listed boundary particle's pressure
        p_b = sum_f p_f W_bf / sum_f W_bf + max(0, rho0 sum_f g . (x_b - x_f) W_bf / sum_f W_bf) (bval),
        and with
        one material p_b / rho_b^2 (bq), rho_b from the inverse of Tait's equation."""
        for t in range(n_active[None]):
            b = active[t]
            acc = ti.cast(0.0, f)
            for k in range(bnb_cnt[b]):
                j = bnb_j[b, k]
                if j < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                acc += bnb_w[b, k] * p_liq[j]
            if ti.static(uniform):
                acc += mat_rho0[0] * bhyd[b]
            else:
                acc += bhyd[b]
            pb = acc
            if ti.static(clamp):
                pb = ti.max(acc, 0.0)
            if ti.static(filt):
                if (
                    pbar[b] > NEW
                ):  # wetted in the last substep too (NEW: newly wetted, takes the extrapolation)
                    pb = pbar[b] + (dt / (TAU + dt)) * (pb - pbar[b])
                pbar[b] = pb
            bval[b] = pb
            if ti.static(uniform):
                rb = mat_rho0[0] * ti.pow(pb / mat_k[0] + 1.0, 1.0 / mat_n[0])
                bq[b] = pb / (rb * rb)

    @ti.func
    def wcsph_wall_force(i):
        """-rho0_i sum_b V_b (p_b / rho_b^2) grad W_ib over liquid particle i's listed boundary
        neighbours: the
        wall's half of the symmetric pressure force (the particle's own half is Akinci's term)."""
        out = ti.Vector.zero(f, dim)
        xi = x[i]
        m = mid[i]
        for k in range(nb_cnt[i], nbw_end[i]):
            b = nb_j[i, k]
            if b < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                break
            d = xi - bx[b]
            g = ti.Vector.zero(f, dim)
            if ti.static(list_s):
                g = (d * nb_s[i, k]) * bV[b]  # the list's factor (the neighbour pass's grad W)
            else:
                g = gradW(d, ti.sqrt(d.dot(d))) * bV[b]
            q = ti.cast(0.0, f)
            if ti.static(uniform):
                q = bq[b]
            else:
                pb = bval[b]
                rb = mat_rho0[m] * ti.pow(pb / mat_k[m] + 1.0, 1.0 / mat_n[m])
                q = pb / (rb * rb)
            out -= q * g
        return mat_rho0[m] * out

    return SimpleNamespace(
        bval=bval,
        bhyd=bhyd,
        mark=mark,
        update=update,
        wall_sum=wall_sum,
        wcsph_pressure=wcsph_pressure,
        wcsph_wall_force=wcsph_wall_force,
        pbar=pbar,
        bq=bq,
    )
