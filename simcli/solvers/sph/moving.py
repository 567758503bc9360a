"""Colliders in prescribed motion and the loads on named colliders, for SPH (built on
simcli.colliders.ColliderPoses, the path MPM, PBD and FEM share; a collider whose motion is integrated
instead of prescribed, a rigid body, goes the same way).

* **Moving boundary.** A collider's boundary particles are sampled once, in its body frame (its pose at
  t = 0, the whole shell, not clipped to the domain). Every substep, before the neighbour search, each
  moving collider's particles take its pose at the middle of the substep (ColliderPoses slot 0):
  ``x_b = R (x0_b - p) + c`` and the surface velocity ``v_b = v + w x (x_b - c)``, and the boundary
  particles are re-sorted into the cell grid (the same counting sort as the liquid's; walls and still
  colliders stay in their cells, and the sort keeps their relative order). The velocity ``v_b`` enters
  the boundary condition where the static walls' velocity did: DFSPH's density rate (sum_b V_b v_b .
  grad W_ib, so the pressure solves make the liquid's normal velocity follow the wall) and no-slip
  viscosity; WCSPH sees the wall through the density sum it compresses. The cells that test for boundary
  neighbours (``bnear``) are the walls' and still colliders' (fixed at the build) plus those within reach
  of a moving boundary particle (a moving collider's or rigid body's, a deformable body's sample), marked
  every substep after the sort (``mark_near``), so the liquid far from every boundary skips the scan as
  with still walls (C1, an MPM duck in a water box: 25.7 substeps/s at best against 22.3; C1's water with a
  free rigid box: 6% less kernel time a substep; docs/PERFORMANCE.md).
* **No particle inside.** The advection's last guard pushes a particle that ended inside a collider
  (its body-frame signed distance at the substep's end pose, slot 1) onto its surface and removes its
  normal velocity into the surface relative to the surface's own velocity (boundary.make_pushout).
* **Loads.** A named collider (still or moving) receives the reaction of every force its boundary
  particles put on the liquid during the substep, summed over liquid-boundary pairs and applied at the
  boundary particle (ColliderPoses.add_load: impulse, and its moment about the moving pivot):

  - WCSPH: ``J_b = dt m_i rho0_i V_b (p_i / rho_i^2 + p_b / rho_b^2) grad W_ib`` (Akinci's term and, with
    ``wall_pressure: extrapolated``, the wall's own pressure), collected after the pressure force;
  - DFSPH: the pressure solves apply ``-dt V_b (k_i L_i + k_b) grad W_ib`` per iteration with fixed
    gradients, so their sum is the same expression in the total stiffness of the substep, ``K_i`` (the
    divergence and density solves' sums, ``kacc + kappav / dt``) and ``K_b`` (the Shepard average of K
    over the boundary particle's liquid neighbours, which is linear, plus its hydrostatic part):
    ``J_b = dt m_i V_b (K_i L_i + K_b) grad W_ib``, collected before the advection;
  - no-slip viscosity (``boundary: sticky``): ``J_b = -dt m_i visc_c nu_i V_b ((v_i - v_b) . d) grad W_ib
    / (r^2 + eps)``, from the velocities the viscosity used.

  The sums are atomic f64 additions (their order, hence the last bits of a load, may depend on the thread
  schedule; they never feed back into the liquid).
"""

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams

with stdout_to_stderr():
    import taichi as ti


def moving_bounds(spec, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """A box holding the whole collider in its body frame, to sample its shell without clipping it to the
    domain (a moving collider may enter the domain later); a Plane (unbounded) gets the domain box grown by
    its diagonal on each side."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    a = np.asarray(spec.a, dtype=np.float64)
    if spec.kind == "Box":
        return a, np.asarray(spec.b, dtype=np.float64)
    if spec.kind == "Sphere":
        return a - spec.radius, a + spec.radius
    if spec.kind == "Cylinder":
        r = max(spec.radius, spec.half_height)
        return a - r, a + r
    if spec.kind == "Mesh":
        return spec.mesh.bounds
    ext = float(np.linalg.norm(hi - lo))
    return lo - ext, hi + ext


def make_moving_boundary(
    P: SPHParams, F: SPHFields, fn: SPHFuncs, poses, grid, deformable=None, near_static=None
):
    """``move()`` (a Taichi func, called at kernel scope before the liquid's sort): every moving collider's
    boundary particles to the substep's middle pose, with the surface velocity, then the boundary
    particles re-sorted into the cells. Fields moved along by the sort: position, volume, velocity,
    no-slip flag, body-frame position, collider index, a deformable body's sample index, and WCSPH's
    relaxing wall pressure (``fn.wall_pressure`` must be built). ``poses``: the solver's ColliderPoses;
    ``grid``: its CellGrid; ``deformable``: a DeformableBoundary (deformable.py) or None: its samples take
    the positions and velocities the coupling phase left in its ``sx``, ``sv``. ``near_static``: the cells
    with a wall or still collider particle in reach: ``mark_near`` (a Taichi func, called by ``move`` after
    the sort, and after a checkpoint's restore) sets ``F.bnear`` to it plus the cells within reach of a
    moving boundary particle, so that the liquid far from every boundary skips the boundary scan as with
    still walls. Returns (move, mark_near); mark_near is None without ``near_static``."""
    from simcli.solvers.sph.neighbours import make_neighbour_funcs

    f, dim, nbp = P.f, P.dim, max(1, P.nbp)
    specs = poses.specs
    moving = [k for k, c in enumerate(specs) if c.moving]
    bx, bvel, bx0, bcol, bsrc = F.bx, F.bvel, F.bx0, F.bcol, F.bsrc
    move = [F.bx, F.bV, F.bvel, F.bns]
    tmp = [
        ti.Vector.field(dim, f, shape=nbp),
        ti.field(f, shape=nbp),
        ti.Vector.field(dim, f, shape=nbp),
        ti.field(ti.i32, shape=nbp),
    ]
    if bx0 is not None:  # colliders driven through ColliderPoses
        move += [bx0, bcol]
        tmp += [ti.Vector.field(dim, f, shape=nbp), ti.field(ti.i32, shape=nbp)]
    if bsrc is not None:  # a deformable boundary's samples (deformable.py)
        move.append(bsrc)
        tmp.append(ti.field(ti.i32, shape=nbp))
    wp = fn.wall_pressure
    if wp is not None and wp.pbar is not None:
        move.append(wp.pbar)
        tmp.append(ti.field(f, shape=nbp))
    sort, cell_coords, linear = make_neighbour_funcs(
        grid,
        f,
        P.cpu,
        {
            "x": F.bx,
            "move": move,
            "move_tmp": tmp,
            "cell_id": ti.field(ti.i32, shape=nbp),
            "rank": ti.field(ti.i32, shape=nbp),
            "count": ti.field(ti.i32, shape=grid.ncells),
            "start": F.bstart,
            "block_sum": ti.field(ti.i32, shape=grid.nblocks),
        },
    )
    n_b = P.nbp

    db = deformable
    has_db = db is not None
    dyn_near = near_static is not None
    mark_near = None
    if dyn_near:
        bnear, ncells, R = F.bnear, grid.ncells, grid.R
        side = 2 * R + 1
        hi_c = ti.Vector([d - 1 for d in grid.dims])

        @ti.func
        def is_moving(b):
            m = False
            if ti.static(has_db):
                m = bsrc[b] >= 0
            if ti.static(len(moving) > 0):
                kb = bcol[b]
                for k in ti.static(moving):
                    if kb == k:
                        m = True
            return m

        @ti.func
        def mark_near():
            for c in range(ncells):
                bnear[c] = near_static[c]
            # a moving boundary particle (a moving collider's, a sample's) is in reach of the liquid within R
            # cells of it; one outside the domain marks the edge cells it clamps to (more scans, never fewer)
            for b in range(n_b):
                if is_moving(b):
                    cb = cell_coords(bx[b])
                    for k in range(side**dim):
                        o = ti.Vector([(k // side**d) % side - R for d in ti.static(range(dim))])
                        bnear[linear(ti.min(ti.max(cb + o, 0), hi_c))] = ti.cast(1, ti.i8)

    @ti.func
    def move_boundary():
        if ti.static(len(moving) > 0):
            for b in range(n_b):
                kb = bcol[b]
                for k in ti.static(moving):
                    if kb == k:
                        R, c, v, w = poses.get(0, k)
                        xw = R @ (bx0[b] - poses.pivot[k]) + c
                        bx[b] = xw
                        bvel[b] = v + poses.cross(w, xw - c)
        if ti.static(has_db):  # samples of a deformable body: where the coupling put them
            for b in range(n_b):
                s = bsrc[b]
                if s >= 0:
                    bx[b] = db.sx[s]
                    bvel[b] = db.sv[s]
        sort(n_b)
        if ti.static(dyn_near):
            mark_near()

    return move_boundary, mark_near


def make_loads(P: SPHParams, F: SPHFields, fn: SPHFuncs, poses, deformable=None):
    """Taichi funcs that add the liquid's loads on the named colliders to ``poses`` (the solver's
    ColliderPoses; see the module docstring): ``pressure(i, dt)`` (WCSPH after its force pass; DFSPH in
    ``finish`` with the substep's total stiffness in ``F.kk`` and its Shepard average in the wall pressure's
    ``bval``) and ``viscous(i, dt)``. With ``deformable`` (a DeformableBoundary, deformable.py) ``pressure``
    also adds each of its samples' share, the same pair impulse, to the sample's ``simp`` (f64), which
    the coupling phase hands to the body's vertices."""
    f, dim = P.f, P.dim
    specs = poses.specs
    named = [k for k, c in enumerate(specs) if c.name is not None]
    named_noslip = [k for k in named if specs[k].contact == "sticky"] if P.has_noslip else []
    x, v, rho, p, mid = F.x, F.v, F.rho, F.p, F.mid
    bx, bV, bvel, bcol, bstart, bsrc = F.bx, F.bV, F.bvel, F.bcol, F.bstart, F.bsrc
    db = deformable
    has_db = db is not None
    mat_rho0, mat_nu = F.mat_rho0, F.mat_nu
    rows, row_cell, gradW, h2 = fn.rows, fn.row_cell, fn.gradW, P.h2
    R = P.R
    row = 2 * R + 1
    dfsph = P.pressure_solver == "DFSPH"
    wp = fn.wall_pressure
    ext = wp is not None
    uniform = P.uniform
    kgc, kgc_scalar, Lm, Lc = P.kgc, P.kgc_scalar, F.Lm, F.Lc
    kk = F.kk
    from simcli.solvers.sph.dfsph import BFAC
    from simcli.solvers.sph.kernels import VISC_EPS

    eps_visc = VISC_EPS * h2
    visc_c = 2.0 * (dim + 2)
    bq = wp.bq if ext and not dfsph else None
    bval, bhyd = (wp.bval, wp.bhyd) if ext else (None, None)
    mat_k, mat_n = F.mat_k, F.mat_n

    @ti.func
    def pair_impulse(i, b, d, g, dt):
        """The impulse boundary particle b's pressure gave liquid particle i this substep, reversed (the
        collider's share), for g = grad W(x_i - x_b)."""
        mi = fn.mass_of(i)
        J = ti.Vector.zero(f, dim)
        if ti.static(dfsph):
            gi = g
            if ti.static(kgc_scalar):
                gi = Lc[i] * g
            elif ti.static(kgc):
                gi = Lm[i] @ g
            J = BFAC * kk[i] * gi
            if ti.static(ext):
                kb = bval[b] + bhyd[b]
                if ti.static(not uniform):
                    kb /= mat_rho0[mid[i]]
                J += kb * g
            J *= dt * mi * bV[b]
        else:
            ri = rho[i]
            q = p[i] / (ri * ri)
            if ti.static(ext):
                if ti.static(uniform):
                    q += bq[b]
                else:
                    m = mid[i]
                    pb = bval[b]
                    rb = mat_rho0[m] * ti.pow(pb / mat_k[m] + 1.0, 1.0 / mat_n[m])
                    q += pb / (rb * rb)
            J = (dt * mi * mat_rho0[mid[i]] * bV[b] * q) * g
        return J

    @ti.func
    def for_pairs(i, dt, viscous: ti.template()):
        """Liquid particle i's boundary neighbours that collect a load: a named collider's particles (the
        pressure impulse, or with ``viscous`` the no-slip viscosity's) and, for the pressure, a deformable
        body's samples (to their ``simp``)."""
        xi = x[i]
        c0 = rows(xi)
        for a in range(row ** (dim - 1)):
            lin = row_cell(c0, a)
            for b in range(bstart[lin], bstart[lin + row]):
                if b < 0:  # never: keeps the pair loop scalar (neighbours.py, Scalar pair loops)
                    break
                kb = -1
                if ti.static(len(named) > 0):
                    kb = bcol[b]
                s = -1
                if ti.static(has_db and not viscous):
                    s = bsrc[b]
                if kb >= 0 or s >= 0:
                    d = xi - bx[b]
                    r2 = d.dot(d)
                    if r2 < h2:
                        g = gradW(d, ti.sqrt(r2))
                        for k in ti.static(named_noslip if viscous else named):
                            if kb == k:
                                J = ti.Vector.zero(f, dim)
                                if ti.static(viscous):
                                    coef = visc_c * mat_nu[mid[i]] * bV[b] / (r2 + eps_visc)
                                    J = -dt * fn.mass_of(i) * coef * (v[i] - bvel[b]).dot(d) * g
                                else:
                                    J = pair_impulse(i, b, d, g, dt)
                                poses.add_load(k, bx[b], J, 0)
                        if ti.static(has_db and not viscous):
                            if s >= 0:
                                ti.atomic_add(db.simp[s], ti.cast(pair_impulse(i, b, d, g, dt), ti.f64))

    @ti.func
    def pressure(i, dt):
        if ti.static(len(named) > 0 or has_db):
            for_pairs(i, dt, False)

    @ti.func
    def viscous(i, dt):
        if ti.static(len(named_noslip) > 0):
            for_pairs(i, dt, True)

    return pressure, viscous
