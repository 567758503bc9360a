"""Position-based fluids (Macklin and Mueller 2013, "Position based fluids") for PBD.Liquid particles.

Per substep, after the prediction: neighbour lists from a hashed cell grid (cell = smoothing length h =
2 x particle_size, 27 cells), then ``density_iterations`` times

    rho_i = sum_j m_j W(x_i - x_j)                        (poly6)
    C_i = max(rho_i / rho0 - 1, 0)                        (unilateral: a free surface does not pull)
    lambda_i = -C_i / (sum_k |grad_k C_i|^2 + eps)        (eq. 11)
    dx_i = sum_j V (lambda_i + lambda_j + s_corr) grad W(x_i - x_j)   (spiky gradient, eq. 14)
    s_corr = -k (W(r) / W(0.2 h))^4 / S0                  (artificial pressure, eq. 13)

and walls/colliders as position clamps; after the velocity update, optional vorticity confinement and XSPH
viscosity
v_i += c sum_j V_j (v_j - v_i) W_ij (eq. 17). rho0 is the lattice sum m sum_j W of an interior particle
of the initial lattice (so the initial block is at rest density exactly; the particle mass is rho x
volume / count), S0 the same particle's sum |grad C|^2: eps = density_relaxation x S0 and s_corr's k are
dimensionless. Liquid particles see only liquid neighbours (no two-way coupling with cloth or solids).

Active mode (emitters and sinks, simcli/solvers/sources.py): one pass over the solver's active particles
[0, count()) instead of one per entity; ``lid`` (per particle) picks each liquid particle's parameters
(density relaxation, artificial pressure, viscosity, vorticity; -1: not a liquid, skipped) and every
liquid sees every other (a jet pours into a pool). Masses are per particle: rho0_i = m_i sum W (the
lattice sum), V = 1 / sum W for all, the wall tables scale with m_i.
"""

import math

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.solvers.pbd.hashgrid import HashGrid

with stdout_to_stderr():
    import taichi as ti

CAPACITY = 64  # neighbours kept per particle (26 on the rest lattice at h = 2 x spacing)
S_CORR_K, S_CORR_DQ, S_CORR_N = 0.1, 0.2, 4


def poly6_const(h: float, dim: int = 3) -> float:
    """The poly6 kernel's normalisation: W(r) = c (h^2 - r^2)^3 integrates to 1 over the ball (3D) or the
    disk (2D) of radius h: 315 / (64 pi h^9) in 3D, 4 / (pi h^8) in 2D."""
    return 315.0 / (64.0 * math.pi * h**9) if dim == 3 else 4.0 / (math.pi * h**8)


def spiky_const(h: float, dim: int = 3) -> float:
    """dW/dr = c (h - r)^2 of the spiky kernel W = 15 / (pi h^6) (h - r)^3 (3D), 10 / (pi h^5) (h - r)^3
    (2D): -45 / (pi h^6), -30 / (pi h^5)."""
    return -45.0 / (math.pi * h**6) if dim == 3 else -30.0 / (math.pi * h**5)


def poly6(r: np.ndarray, h: float, dim: int = 3) -> np.ndarray:
    return np.where(r < h, poly6_const(h, dim) * (h * h - r * r) ** 3, 0.0)


def spiky_grad_mag(r: np.ndarray, h: float, dim: int = 3) -> np.ndarray:
    return np.where((r < h) & (r > 0), spiky_const(h, dim) * (h - r) ** 2, 0.0)


WALL_SAMPLES = 49  # 4k + 1: the rest lattice's distances ps/2 + k ps fall on samples (h = 2 ps)


def wall_tables(spacing: float, h: float, mass: float, dim: int = 3):
    """Density [kg/m^3] a particle at distance d (0..h, WALL_SAMPLES samples) from a domain wall gets from
    virtual particles behind it: the fluid lattice mirrored (layers ps/2 + k ps behind the wall), so a
    particle of the rest lattice next to a wall sees exactly the neighbours it misses. Where two walls
    meet, both half-spaces hold the quarter-space behind the edge: its density (a table over the two
    distances) is subtracted once (inclusion-exclusion; the octants behind the 8 corners are left
    subtracted, a slight undercount on the safe side). Returns (d, rho_wall(d), d rho_wall/dd,
    rho_edge(d1, d2), its derivatives along d1 and d2). 2D (``dim`` 2): the lattice along the wall is a row,
    the "edge" a corner (the quadrant behind two walls), the 2D kernel's normalisation."""
    k = math.ceil(h / spacing)
    g = np.arange(-k, k + 1) * spacing
    d = np.linspace(0.0, h, WALL_SAMPLES)
    behind = spacing / 2 + np.arange(k + 1) * spacing
    A = d[:, None] + behind[None, :]  # distance behind a wall of each layer, (d, k)
    if dim == 2:
        # half-plane: the row along the wall x layers behind; quadrant behind a corner: layers behind both
        r = np.sqrt(g[None, None, :] ** 2 + A[:, :, None] ** 2)
        half = mass * poly6(r, h, 2).sum(axis=(1, 2))
        r2 = A[:, None, :, None] ** 2 + A[None, :, None, :] ** 2
        quarter = mass * poly6(np.sqrt(r2), h, 2).sum(axis=(2, 3))  # (d1, d2)
    else:
        # half-space: lateral lattice (2D) x layers behind
        lat = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        dz = d[:, None, None] + behind[None, :, None]
        r = np.sqrt((lat**2).sum(axis=1)[None, None, :] + dz**2)
        half = mass * poly6(r, h).sum(axis=(1, 2))
        # quarter-space behind an edge: layers behind both walls x the lattice along the edge
        r2 = (
            A[:, None, :, None, None] ** 2
            + A[None, :, None, :, None] ** 2
            + g[None, None, None, None, :] ** 2
        )
        quarter = mass * poly6(np.sqrt(r2), h).sum(axis=(2, 3, 4))  # (d1, d2)
    return (
        d,
        half,
        np.gradient(half, d),
        quarter,
        np.gradient(quarter, d, axis=0),
        np.gradient(quarter, d, axis=1),
    )


def lattice_constants(spacing: float, h: float, dim: int = 3) -> tuple[float, float]:
    """(sum_j W, S0 / V^2) of an interior particle of a cubic (2D: square) lattice: sum W (self included) and
    |sum grad W|^2 + sum |grad W|^2 (the first is 0 by symmetry)."""
    k = math.ceil(h / spacing)
    g = np.arange(-k, k + 1)
    off = np.stack(np.meshgrid(*([g] * dim), indexing="ij"), -1).reshape(-1, dim) * spacing
    r = np.linalg.norm(off, axis=1)
    gm = spiky_grad_mag(r, h, dim)
    return float(poly6(r, h, dim).sum()), float((gm * gm).sum())


class PBFLiquid:
    """Fields and kernels of the position-based fluid pass over the liquid particles [lo, hi)."""

    def __init__(
        self,
        solver,
        lo: int,
        hi: int,
        spacing: float,
        mass: float,
        opts,
        materials,
        k_corr: float,
        active=None,
    ):
        """``active``: None, or (count func, per-particle mass field, lid field, parameter field (liquids,
        4): eps relative to S0, k_corr, viscosity c, vorticity eps_v) with lo = 0 and hi the capacity."""
        f = solver.f
        act = active is not None
        self.lo, self.hi = lo, hi
        n = hi - lo
        h = 2.0 * spacing
        self.h = h
        D = solver.dim  # 3, or 2 in a 2D scene (masses per metre of depth, the 2D kernels)
        wsum, gsum = lattice_constants(spacing, h, D)
        rho0 = mass * wsum
        vol = mass / rho0
        count = mass_f = lid = par = None  # (closure cells of the funcs below, unused without active)
        if act:
            count, mass_f, lid, par = active
            vol = 1.0 / wsum
            rho0 = mass * wsum  # (the first liquid's, reported in run.json)
        s0 = vol * vol * gsum  # sum_k |grad_k C|^2 of a rest-lattice particle [1/m^2]
        self.rho0, self.s0 = rho0, s0
        relax, visc, self.vort = materials
        eps = relax * s0
        wdq = float(poly6(np.array([S_CORR_DQ * h]), h, D)[0])
        self.iterations = opts.density_iterations
        # active mode: tables per unit mass, scaled by each particle's mass
        _, half, dhalf, quarter, dq1, dq2 = wall_tables(spacing, h, 1.0 if act else mass, D)
        rho0_div = wsum if act else rho0  # a wall gradient's density over rho0
        npf = solver.npf
        w_half = ti.field(f, shape=WALL_SAMPLES)
        w_dhalf = ti.field(f, shape=WALL_SAMPLES)
        w_q = ti.field(f, shape=(WALL_SAMPLES, WALL_SAMPLES))
        w_dq1 = ti.field(f, shape=(WALL_SAMPLES, WALL_SAMPLES))
        w_dq2 = ti.field(f, shape=(WALL_SAMPLES, WALL_SAMPLES))
        for fld, arr in ((w_half, half), (w_dhalf, dhalf), (w_q, quarter), (w_dq1, dq1), (w_dq2, dq2)):
            fld.from_numpy(arr.astype(npf))
        dom_lo, dom_hi = solver.dom_lo, solver.dom_hi
        wstep = h / (WALL_SAMPLES - 1)
        use_walls = opts.liquid_walls
        x, v, w = solver.x, solver.v, solver.w

        @ti.func
        def npts():
            out = n
            if ti.static(act):
                out = count()
            return out

        @ti.func
        def m_of(a):
            out = mass
            if ti.static(act):
                out = mass_f[lo + a]
            return out

        @ti.func
        def liquid(a):
            out = True
            if ti.static(act):
                out = lid[lo + a] >= 0
            return out

        self.grid = grid = HashGrid(x, lo, n, h, npts if act else None)
        start, srt, cell_of = grid.start, grid.sorted, grid.cell_of
        if D == 3:
            cells = [(t // 9 - 1, (t // 3) % 3 - 1, t % 3 - 1) for t in range(27)]
        else:
            cells = [(t // 3 - 1, t % 3 - 1) for t in range(9)]
        around = grid.slots_around(cells)
        nb = ti.field(ti.i32, shape=(n, CAPACITY))
        nnb = ti.field(ti.i32, shape=n)
        lam = ti.field(f, shape=n)
        rho = ti.field(f, shape=n)
        dpos = ti.Vector.field(D, f, shape=n)
        dvel = ti.Vector.field(D, f, shape=n)
        self.rho = rho
        self.overflow = ti.field(ti.i32, shape=())
        overflow = self.overflow
        c6 = poly6_const(h, D)
        cs = spiky_const(h, D)

        @ti.func
        def W(r):
            out = 0.0
            if r < h:
                out = c6 * (h * h - r * r) ** 3
            return out

        @ti.func
        def gradW(d, r):
            out = ti.Vector.zero(float, D)
            if r < h and r > 1e-9:
                out = cs * (h - r) ** 2 * d / r
            return out

        @ti.func
        def coord(dist):
            u = ti.min(ti.max(dist, 0.0) / wstep, WALL_SAMPLES - 1.0001)
            i0 = ti.cast(u, ti.i32)
            return i0, u - i0

        @ti.func
        def walls(xi):
            """Density of the walls' virtual particles at xi and its gradient in C units (1/m)."""
            rw = 0.0
            gw = ti.Vector.zero(float, D)
            dist = ti.Vector.zero(float, 2 * D)
            sgn = ti.Vector([1.0, -1.0] * D)  # d dist / dx along its axis
            for ax in ti.static(range(D)):
                dist[2 * ax] = xi[ax] - dom_lo[None][ax]
                dist[2 * ax + 1] = dom_hi[None][ax] - xi[ax]
            for q in ti.static(range(2 * D)):
                if dist[q] < h:
                    i0, t = coord(dist[q])
                    rw += (1 - t) * w_half[i0] + t * w_half[i0 + 1]
                    gw[q // 2] += sgn[q] * ((1 - t) * w_dhalf[i0] + t * w_dhalf[i0 + 1]) / rho0_div
            for q1 in ti.static(range(2 * D)):
                for q2 in ti.static(range(2 * D)):
                    if ti.static(q1 // 2 < q2 // 2):  # noqa: SIM102 - two walls of different axes: an edge
                        if dist[q1] < h and dist[q2] < h:
                            i, t = coord(dist[q1])
                            j, u = coord(dist[q2])
                            wq = (
                                (1 - t) * (1 - u) * w_q[i, j]
                                + t * (1 - u) * w_q[i + 1, j]
                                + (1 - t) * u * w_q[i, j + 1]
                                + t * u * w_q[i + 1, j + 1]
                            )
                            d1 = (
                                (1 - t) * (1 - u) * w_dq1[i, j]
                                + t * (1 - u) * w_dq1[i + 1, j]
                                + (1 - t) * u * w_dq1[i, j + 1]
                                + t * u * w_dq1[i + 1, j + 1]
                            )
                            d2 = (
                                (1 - t) * (1 - u) * w_dq2[i, j]
                                + t * (1 - u) * w_dq2[i + 1, j]
                                + (1 - t) * u * w_dq2[i, j + 1]
                                + t * u * w_dq2[i + 1, j + 1]
                            )
                            rw -= wq
                            gw[q1 // 2] -= sgn[q1] * d1 / rho0_div
                            gw[q2 // 2] -= sgn[q2] * d2 / rho0_div
            return rw, gw

        # Free rigid bodies (simcli.rigid): the same half-space of virtual particles behind each face, by the
        # body's signed distance (its faces as walls: without it the liquid next to a body has a deficient
        # density, carries no pressure and packs against it), and the reaction of that wall term, -m dx / dt,
        # to the body. None without rigid bodies (the kernels are then what they were).
        cols = solver.cols
        rigid = [k for k, c in enumerate(cols) if getattr(c, "rigid", False)] if use_walls else []
        poses = solver.poses
        col_a, col_b, col_r, col_hh = solver.col_a, solver.col_b, solver.col_r, solver.col_hh
        # Mesh bodies: a density map (simcli.solvers.pbd.density_map) in place of the tangent half-space
        dmaps = [None] * len(cols)
        if rigid:
            from simcli.solvers.pbd.density_map import DensityMapField, build_density_map

            d_tab = np.linspace(0.0, h, WALL_SAMPLES)
            for k in rigid:
                if cols[k].kind == "Mesh":
                    dmaps[k] = DensityMapField(
                        *build_density_map(cols[k].mesh, spacing, h, 1.0 if act else mass, d_tab, half), f
                    )
        from simcli.colliders import sdf_cylinder, sdf_sphere

        @ti.func
        def quarter(d1, d2):
            """The quarter-space table at distances d1, d2 behind two perpendicular planes: density and its
            derivatives along d1 and d2 (bilinear, as walls())."""
            i, t = coord(d1)
            j, u = coord(d2)
            c00, c10, c01, c11 = (1 - t) * (1 - u), t * (1 - u), (1 - t) * u, t * u
            wq = c00 * w_q[i, j] + c10 * w_q[i + 1, j] + c01 * w_q[i, j + 1] + c11 * w_q[i + 1, j + 1]
            g1 = c00 * w_dq1[i, j] + c10 * w_dq1[i + 1, j] + c01 * w_dq1[i, j + 1] + c11 * w_dq1[i + 1, j + 1]
            g2 = c00 * w_dq2[i, j] + c10 * w_dq2[i + 1, j] + c01 * w_dq2[i, j + 1] + c11 * w_dq2[i + 1, j + 1]
            return wq, g1, g2

        @ti.func
        def body_wall(k: ti.template(), xi):
            """Density of rigid body k's virtual particles at xi and its gradient in C units (1/m). A Box: its
            solid as the intersection of its faces' half-spaces, in the body frame: outside one face, that
            face's half-space less the quarter-spaces beyond each neighbouring face within reach; outside
            two (an edge), the quarter-space behind both (the corners' octants are left out, as walls()
            leaves them). Sphere and Cylinder: the half-space behind the tangent plane at its distance. Mesh:
            its density map (density_map.py: the kernel's share of the solid, as a wall's table)."""
            xq = poses.to_body(k, xi, 1)
            rw = 0.0
            gb = ti.Vector.zero(float, D)  # in the body frame
            if ti.static(cols[k].kind == "Box"):
                lo_, hi_ = col_a[k], col_b[k]
                o = ti.Vector.zero(
                    float, D
                )  # distance outside along each axis (< 0: inside, to the nearer face)
                sd = ti.Vector.zero(float, D)  # the outward direction of that face along its axis
                nout = 0
                for ax in ti.static(range(D)):
                    s_lo = lo_[ax] - xq[ax]
                    s_hi = xq[ax] - hi_[ax]
                    if s_lo > s_hi:
                        o[ax], sd[ax] = s_lo, -1.0
                    else:
                        o[ax], sd[ax] = s_hi, 1.0
                    if o[ax] > 0:
                        nout += 1
                if nout <= 1:
                    asel = 0  # the axis it is outside (or nearest to the surface, inside)
                    for ax in ti.static(range(1, D)):
                        if o[ax] > o[asel]:
                            asel = ax
                    for A in ti.static(range(D)):
                        dA = ti.max(o[A], 0.0)
                        if A == asel and dA < h:
                            i0, t = coord(dA)
                            rw = (1 - t) * w_half[i0] + t * w_half[i0 + 1]
                            gb[A] += sd[A] * ((1 - t) * w_dhalf[i0] + t * w_dhalf[i0 + 1])
                            for B in ti.static(range(D)):
                                if ti.static(B != A):
                                    if -o[B] < h:
                                        wq, g1, g2 = quarter(dA, -o[B])
                                        rw -= wq
                                        gb[A] -= sd[A] * g1
                                        gb[B] += sd[B] * g2  # d(-o_B)/dx = -sd_B along B
                elif nout == 2:
                    for A in ti.static(range(D)):
                        for B in ti.static(range(A + 1, D)):
                            if o[A] > 0 and o[B] > 0 and o[A] < h and o[B] < h:
                                wq, g1, g2 = quarter(o[A], o[B])
                                rw = wq
                                gb[A] += sd[A] * g1
                                gb[B] += sd[B] * g2
            else:
                phi = 1.0
                nrm = ti.Vector.zero(float, D)
                if ti.static(cols[k].kind == "Sphere"):
                    phi, nrm = sdf_sphere(xq, col_a[k], col_r[k])
                elif ti.static(cols[k].kind == "Cylinder" and D == 3):
                    phi, nrm = sdf_cylinder(xq, col_a[k], col_r[k], col_hh[k], cols[k].axis)
                if ti.static(cols[k].kind == "Mesh" and D == 3):
                    rw, gb = dmaps[k].sample(xq)
                elif phi < h:
                    i0, t = coord(phi)
                    rw = (1 - t) * w_half[i0] + t * w_half[i0 + 1]
                    gb = nrm * ((1 - t) * w_dhalf[i0] + t * w_dhalf[i0 + 1])
            return rw, poses.normal_to_world(k, gb, 1) / rho0_div

        @ti.kernel
        def neighbours():
            grid.build()
            for a in range(npts()):
                sl = around(cell_of(x[lo + a]))  # the 3 x 3 (x 3) cells around a's
                m = 0
                for t in ti.static(range(len(cells))):
                    s = sl[t]
                    if not liquid(a):
                        s = -1
                    for q in range(start[ti.max(s, 0)], start[s + 1]):  # empty for s = -1
                        b = srt[q]
                        if b != a and liquid(b) and (x[lo + a] - x[lo + b]).norm() < h:
                            if m < CAPACITY:
                                nb[a, m] = b
                                m += 1
                            else:
                                overflow[None] = 1
                nnb[a] = m

        @ti.kernel
        def density_step(k_corr: float):
            for a in range(npts()):
                xi = x[lo + a]
                r_i = mass * W(0.0)
                if ti.static(act):
                    r_i = m_of(a) * W(0.0)
                gi = ti.Vector.zero(float, D)
                g2 = 0.0
                for m in range(nnb[a]):
                    d = xi - x[lo + nb[a, m]]
                    r = d.norm()
                    if ti.static(act):
                        r_i += m_of(nb[a, m]) * W(r)
                    else:
                        r_i += mass * W(r)
                    gj = vol * gradW(d, r)
                    gi += gj
                    g2 += gj.norm_sqr()
                if ti.static(use_walls):
                    rw, gw = walls(xi)
                    for k in ti.static(rigid):
                        rb, gb = body_wall(k, xi)
                        rw += rb
                        gw += gb
                    if ti.static(act):
                        r_i += m_of(a) * rw
                    else:
                        r_i += rw
                    gi += gw
                if ti.static(act):
                    if not liquid(a):
                        r_i = 0.0
                    rho[a] = r_i
                    C = ti.max(r_i / (m_of(a) * wsum) - 1.0, 0.0)
                    lam[a] = -C / (gi.norm_sqr() + g2 + par[ti.max(lid[lo + a], 0)][0] * s0)
                else:
                    rho[a] = r_i
                    C = ti.max(r_i / rho0 - 1.0, 0.0)
                    lam[a] = -C / (gi.norm_sqr() + g2 + eps)
            for a in range(npts()):
                xi = x[lo + a]
                dp = ti.Vector.zero(float, D)
                kc = k_corr
                if ti.static(act):
                    kc = par[ti.max(lid[lo + a], 0)][1]
                for m in range(nnb[a]):
                    b = nb[a, m]
                    d = xi - x[lo + b]
                    r = d.norm()
                    sc = -k_corr * (W(r) / wdq) ** S_CORR_N / s0
                    if ti.static(act):
                        sc = -kc * (W(r) / wdq) ** S_CORR_N / s0
                    dp += (lam[a] + lam[b] + sc) * vol * gradW(d, r)
                if ti.static(use_walls):
                    rw, gw = walls(xi)
                    dp += lam[a] * gw  # the wall moves nothing: i moves along its own constraint's gradient
                    for k in ti.static(rigid):
                        rb, gb = body_wall(k, xi)
                        dp += lam[a] * gb
                        if w[lo + a] > 0:  # the body takes the reaction of the push it gave
                            poses.add_load(k, xi, -(m_of(a) * lam[a] / poses.dt[None]) * gb, 1)
                dpos[a] = dp
            for a in range(npts()):
                if w[lo + a] > 0:
                    x[lo + a] += dpos[a]

        @ti.kernel
        def viscosity(c: float):
            for a in range(npts()):
                dv = ti.Vector.zero(float, D)
                for m in range(nnb[a]):
                    b = nb[a, m]
                    d = x[lo + a] - x[lo + b]
                    if ti.static(act):
                        dv += m_of(b) / ti.max(rho[b], 1e-6) * (v[lo + b] - v[lo + a]) * W(d.norm())
                    else:
                        dv += mass / ti.max(rho[b], 1e-6) * (v[lo + b] - v[lo + a]) * W(d.norm())
                if ti.static(act):
                    dvel[a] = par[ti.max(lid[lo + a], 0)][2] * dv
                else:
                    dvel[a] = c * dv
            for a in range(npts()):
                if w[lo + a] > 0:
                    v[lo + a] += dvel[a]

        # 3D: omega a vector; 2D: the curl's z component, a scalar (N x omega = omega (N_y, -N_x))
        omega = ti.Vector.field(3, f, shape=n) if D == 3 else ti.field(f, shape=n)

        @ti.func
        def curl(g, dv):  # g x dv (2D: its z component)
            if ti.static(D == 3):
                return g.cross(dv)
            else:
                return g[0] * dv[1] - g[1] * dv[0]

        @ti.func
        def omega_abs(a):
            out = 0.0
            if ti.static(D == 3):
                out = omega[a].norm()
            else:
                out = ti.abs(omega[a])
            return out

        @ti.func
        def n_cross_omega(nv, a):  # N x omega (2D: omega along z)
            out = ti.Vector.zero(float, D)
            if ti.static(D == 3):
                out = nv.cross(omega[a])
            else:
                out = omega[a] * ti.Vector([nv[1], -nv[0]])
            return out

        @ti.kernel
        def vorticity(eps_v: float, dt: float):
            """Vorticity confinement (Macklin and Mueller 2013 eqs. 15-16; Fedkiw et al. 2001): curl
            omega_i = sum_j V grad W_ij x (v_j - v_i), eta = grad |omega|, N = eta / |eta|, and the
            acceleration eps_v (N x omega) puts back the swirl the position projection damps. In 2D omega
            is the scalar curl (about z) and N x omega = omega (N_y, -N_x)."""
            for a in range(npts()):
                if ti.static(D == 3):
                    cw = ti.Vector.zero(float, 3)
                    for m in range(nnb[a]):
                        b = nb[a, m]
                        d = x[lo + a] - x[lo + b]
                        cw += vol * curl(gradW(d, d.norm()), v[lo + b] - v[lo + a])
                    omega[a] = cw
                else:
                    cz = 0.0
                    for m in range(nnb[a]):
                        b = nb[a, m]
                        d = x[lo + a] - x[lo + b]
                        cz += vol * curl(gradW(d, d.norm()), v[lo + b] - v[lo + a])
                    omega[a] = cz
            for a in range(npts()):
                eta = ti.Vector.zero(float, D)
                wa = omega_abs(a)
                for m in range(nnb[a]):
                    b = nb[a, m]
                    d = x[lo + a] - x[lo + b]
                    eta += vol * (omega_abs(b) - wa) * gradW(d, d.norm())
                le = eta.norm()
                dv = ti.Vector.zero(float, D)
                if le > 1e-9:
                    if ti.static(act):
                        dv = dt * par[ti.max(lid[lo + a], 0)][3] * n_cross_omega(eta / le, a)
                    else:
                        dv = dt * eps_v * n_cross_omega(eta / le, a)
                dvel[a] = dv
            for a in range(npts()):
                if w[lo + a] > 0:
                    v[lo + a] += dvel[a]

        self._neighbours, self._density_step, self._viscosity = neighbours, density_step, viscosity
        self._vorticity = vorticity
        self.visc = visc
        self.k_corr = k_corr

    def project(self, clamp) -> None:
        """The density iterations (after the other constraints); ``clamp()`` keeps particles in the domain
        and out of colliders between iterations."""
        self._neighbours()
        for _ in range(self.iterations):
            self._density_step(self.k_corr)
            clamp()

    def after_velocity(self, dt: float) -> None:
        if self.vort > 0:
            self._vorticity(self.vort, dt)
        if self.visc > 0:
            self._viscosity(self.visc)
