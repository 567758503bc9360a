"""Two-way contact between the MPM material and a set of points without volume (PBD cloth and rope vertices):
a one-sided, position-level contact of each vertex against MPM's volume fraction (docs/COUPLING.md, MPM-PBD).

Why not the grid merge of grid_contact.py: a cloth has no volume, so at a node both touch the merge gives
the light cloth the heavy MPM body's normal velocity wherever their B-splines overlap. A ball on a trampoline
drags the vertices under it along, the cloth's constraints (solved in PBD's own substep, blind to the ball)
pull them back up into it, and the merge, acting on velocities at nodes only, never puts them back below: the
ball passes through (5.6 cells, measured). And a light cloth on sand stops where the B-splines first overlap,
1.5 cells above the sand. What holds a sheet is a contact on the vertices' positions, as PBD's own collider
contact and Jiang et al. 2017 ("Anisotropic elastoplasticity for cloth, knit and hair frictional contact",
a cloth's particles kept out of the MPM material by a contact on the particle level) and Han et al. 2019
(a hybrid MPM for frictional contact between materials) do.

Per substep, after PBD's whole step (vertices at their end positions ``x``) and MPM's grid update (node masses
``m_i``, updated velocities ``v_i``):

1. ``prepare``: MPM's volume fraction on its node box, ``phi_i = sum_p w_ip J_p V0_p / dx^dim`` (as
   grid_contact.py).
2. ``push``: each coupled vertex (mass ``M > 0``) at ``x`` sees the MPM mass ``S = sum_i w_i m_i`` and
   velocity ``v_m = sum_i w_i m_i v_i / S``; in the material's frame (the grid holds the material at the
   substep's start) it is at ``b = x - dt v_m``. Where ``phi(b) > PHI_SURFACE`` (``phi`` and its gradient by
   the B-spline interpolation of the node values) it is inside: if it was outside at ``a`` (its start
   position, or where the last push left it), it goes back to where its path ``a -> b`` entered (sampled
   every MARCH cells, then BISECT bisections) and on along the surface (the path's normal part removed: free
   slip); then up to NEWTON steps onto the level set along ``-grad phi`` (at most MAX_STEP cells each). So
   a sheet keeps its side: a vertex pulled deep into a ball comes back out of the face it went in by, not
   the nearest one. The vertex moves by its share ``S / (S + M)`` of the push (a two-body contact by
   inverse mass).
3. ``relax(dt)``: one more sweep of the set's own constraints (PBD's stretch), then ``push`` again, RELAX
   times: the constraints pull the held vertices back into the body, and each push hands the body that pull.
4. ``finish``: each vertex's velocity changes by its move in this phase over dt (position and velocity stay
   consistent, as PBD's ``(x - xp) / dt``); the sum ``s`` of its pushes goes to MPM as the reaction
   ``-M s / dt``, spread over the nodes it touches in proportion to ``w_i m_i`` (node velocity change
   ``-M s w_i / (S dt)``, so no light node is kicked). Momentum is conserved exactly: ``sum_i m_i dv_i =
   -M s / dt``, and the sweeps move momentum between vertices only (or into pinned ones, as PBD's own step).
   MPM's G2P carries the nodes' change to its particles.

Only nodes inside the domain faces take a reaction (the walls keep MPM's own condition there). A vertex
outside the material is not touched: the contact is one-sided and never pulls, and a sheet's vertices rest on
the material's surface (its ``phi = 1/2`` level set), not a cell and a half above it.
"""

from typing import Any

import numpy as np
import taichi as ti

# The material's surface: half of MPM's volume fraction (a flat face of particles splats phi = 1/2 on the
# plane through their outer faces). NEWTON steps to that level set per substep, each at most MAX_STEP cells.
PHI_SURFACE = 0.5
NEWTON = 3
MAX_STEP = 1.0
# A point that starts a substep outside the material and ends it inside is put back where its path entered:
# the path sampled every MARCH cells (at most MARCH_MAX samples), then BISECT bisections.
MARCH = 0.25
MARCH_MAX = 16
BISECT = 5
# Rounds of the other family's own constraint sweep between pushes (``relax(dt)``, PBD's stretch sweep): a
# light cloth held by a heavy body is pulled back into it by its constraints each sweep; a push after each
# sweep lets the two settle within the substep and hands the body the constraints' whole pull.
RELAX = 8


class SheetContact:
    """MPM <-> a point set without volume: ``n`` points, ``mass(i)`` (0: not coupled), end positions ``x``,
    start positions ``xp`` and velocities ``v`` (vector fields of 3 components, MPM's dim used), ``count()``
    the active points or None, ``relax(dt)`` one more sweep of the set's own constraints or None."""

    def __init__(self, mpm: Any, name: str) -> None:
        self.mpm, self.name = mpm, name
        mpm.store_node_mass = True

    def build(self, n: int, mass: Any, x: Any, xp: Any, v: Any, count: Any = None, relax: Any = None) -> None:
        self.relax = relax
        mpm = self.mpm
        dim, f = mpm.dim, mpm.f
        shape = mpm.grid_shape
        self.vm = ti.field(f, shape=shape)  # MPM's node volume
        npt = max(int(n), 1)
        self.x0 = ti.Vector.field(dim, f, shape=npt)  # each point at the coupling phase's start
        self.xa = ti.Vector.field(dim, f, shape=npt)  # where it last was outside (the grid's frame)
        self.acc = ti.Vector.field(dim, f, shape=npt)  # the sum of its pushes this substep
        self.hits = ti.field(ti.i32, shape=())  # points the first push moved this substep
        fb = 8 if mpm.precision == "f64" else 4
        self.bytes = int(np.prod(shape)) * fb + npt * 3 * dim * fb

        vm, x0, xa, acc, hits = self.vm, self.x0, self.xa, self.acc, self.hits
        grid_v, grid_m, bbox_all = mpm.grid_v, mpm.grid_m, mpm.bbox_all
        flip = mpm.flip
        use_flip = flip is not None
        origin = ti.Vector(list(mpm.origin), dt=f)
        inv_dx = float(mpm.inv_dx)
        dxf = float(mpm.dx)
        base_max = ti.Vector([s - 3 for s in shape])
        lo_node = ti.Vector(list(mpm.lo_node))
        hi_node = ti.Vector(list(mpm.hi_node))
        inv_cell = 1.0 / mpm.dx**dim
        mx, mF, mvol = mpm.x, mpm.F, mpm.vol
        NM = mpm.count
        N = count
        if N is None:

            @ti.func
            def N():
                return n

        phi0 = PHI_SURFACE
        max_step = MAX_STEP * dxf
        march = MARCH * dxf
        eps = 1e-12

        @ti.func
        def stencil(xp):
            Xp = (xp - origin) * inv_dx
            base = ti.min(ti.max(ti.cast(Xp - 0.5, ti.i32), 0), base_max)
            fx = Xp - ti.cast(base, f)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            dw = [(fx - 1.5) * inv_dx, (2.0 - 2.0 * fx) * inv_dx, (fx - 0.5) * inv_dx]
            W = ti.Matrix([[w[a][d] for d in ti.static(range(dim))] for a in ti.static(range(3))])
            D = ti.Matrix([[dw[a][d] for d in ti.static(range(dim))] for a in ti.static(range(3))])
            return base, W, D

        @ti.func
        def weight(W, off):
            wt = ti.cast(1.0, f)
            for d in ti.static(range(dim)):
                wt *= W[off[d], d]
            return wt

        @ti.func
        def usable(I, lo, hi):
            """A node MPM's grid update wrote this substep (its node box) and inside the domain faces."""
            ok = True
            for d in ti.static(range(dim)):
                ok = ok and lo[d] <= I[d] and I[d] < hi[d] and lo_node[d] < I[d] and I[d] < hi_node[d]
            return ok

        @ti.func
        def point(i):
            xi = x[i]
            return ti.Vector([xi[d] for d in ti.static(range(dim))])

        @ti.func
        def start(i):
            xi = xp[i]
            return ti.Vector([xi[d] for d in ti.static(range(dim))])

        @ti.func
        def seen(xe, lo, hi):
            """The MPM mass a point at xe sees (sum w_i m_i) and its momentum (sum w_i m_i v_i)."""
            base, W, D = stencil(xe)
            S = ti.cast(0.0, f)
            P = ti.Vector.zero(f, dim)
            for off in ti.grouped(ti.ndrange(*([3] * dim))):
                I = base + off
                if usable(I, lo, hi):
                    wt = weight(W, off)
                    mI = grid_m[I]
                    if mI > 0:
                        S += wt * mI
                        P += wt * mI * grid_v[I]
            return S, P

        @ti.func
        def fraction(y, lo, hi):
            """MPM's volume fraction at y and its gradient (the B-spline interpolation of the node values)."""
            base, W, D = stencil(y)
            phi = ti.cast(0.0, f)
            g = ti.Vector.zero(f, dim)
            for off in ti.grouped(ti.ndrange(*([3] * dim))):  # a run-time loop: small kernels compile fast
                I = base + off
                inb = True
                for d in ti.static(range(dim)):
                    inb = inb and lo[d] <= I[d] and I[d] < hi[d]
                if inb:
                    val = vm[I]
                    phi += weight(W, off) * val
                    for c in ti.static(range(dim)):
                        gc = D[off[c], c]
                        for d in ti.static(range(dim)):
                            if ti.static(d != c):
                                gc *= W[off[d], d]
                        g[c] += gc * val
            return phi * inv_cell, g * inv_cell

        @ti.kernel
        def prepare():
            lo = bbox_all[0]
            hi = bbox_all[1]
            for p in range(NM()):  # MPM's volumes (current: J V0; F stores H = F - I) onto its node box
                base, W, D = stencil(mx[p])
                Vp = mvol[p] * (ti.Matrix.identity(f, dim) + mF[p]).determinant()
                for off in ti.grouped(ti.ndrange(*([3] * dim))):
                    I = base + off
                    inb = True
                    for d in ti.static(range(dim)):
                        inb = inb and lo[d] <= I[d] and I[d] < hi[d]
                    if inb:
                        vm[I] += weight(W, off) * Vp
            for p in range(N()):
                x0[p] = point(p)
                xa[p] = start(p)  # the grid's frame: where the point was at the substep's start
                acc[p] = ti.Vector.zero(f, dim)

        @ti.kernel
        def push(dt: f):
            """Each point out of the material (its position only; reads the grid)."""
            lo = bbox_all[0]
            hi = bbox_all[1]
            for p in range(N()):
                M = mass(p)
                if M > 0:
                    xe = point(p)
                    S, P = seen(xe, lo, hi)
                    if S > 0:
                        b = xe - dt * (P / S)  # where the point is, in the material's frame (the grid's)
                        phi_b, g_b = fraction(b, lo, hi)
                        y = b
                        if phi_b > phi0:
                            a = xa[p]  # where it last was outside the material
                            phi_a, g_a = fraction(a, lo, hi)
                            if phi_a <= phi0:  # it came in since: back to where its path entered,
                                # then along the surface (the path's normal part removed, free slip)
                                r = b - a
                                ns = ti.min(ti.max(ti.cast(ti.ceil(r.norm() / march), ti.i32), 1), MARCH_MAX)
                                t0 = ti.cast(0.0, f)
                                t1 = ti.cast(1.0, f)
                                for k in range(1, ns):
                                    t = ti.cast(k, f) / ns
                                    ph, gk = fraction(a + t * r, lo, hi)
                                    if ph > phi0:
                                        t1 = t
                                        break
                                    t0 = t
                                for _ in range(BISECT):
                                    tm = 0.5 * (t0 + t1)
                                    ph, gk = fraction(a + tm * r, lo, hi)
                                    if ph > phi0:
                                        t1 = tm
                                    else:
                                        t0 = tm
                                c = a + t0 * r
                                ph, gc = fraction(c, lo, hi)
                                gn = gc.norm()
                                if gn > eps:
                                    nrm = -gc / gn
                                    y = b - ti.min((b - c).dot(nrm), 0.0) * nrm
                                else:
                                    y = c
                        for _ in range(NEWTON):  # onto the surface along -grad phi
                            phi, g = fraction(y, lo, hi)
                            gn = g.norm()
                            if phi <= phi0 or gn <= eps:
                                break
                            step = ((phi - phi0) / gn) * (-g / gn)
                            sn = step.norm()
                            if sn > max_step:
                                step *= max_step / sn
                            y += step
                        mv = (S / (S + M)) * (y - b)  # the point's share of the push
                        acc[p] += mv
                        xa[p] = b + mv
                        if mv.norm_sqr() > 0:
                            hits[None] += 1
                        for d in ti.static(range(dim)):
                            x[p][d] += mv[d]

        @ti.kernel
        def finish(dt: f):
            """Velocities from the moves of the coupling phase; the pushes' reaction onto MPM's nodes."""
            lo = bbox_all[0]
            hi = bbox_all[1]
            for p in range(N()):
                xe = point(p)
                dvp = (xe - x0[p]) / dt
                for d in ti.static(range(dim)):
                    v[p][d] += dvp[d]
                a = acc[p]
                if a.norm_sqr() > 0:
                    base, W, D = stencil(xe)
                    S = ti.cast(0.0, f)
                    for off in ti.grouped(ti.ndrange(*([3] * dim))):
                        I = base + off
                        if usable(I, lo, hi):
                            S += weight(W, off) * grid_m[I]
                    if S > 0:
                        k = -mass(p) / (S * dt)
                        for off in ti.grouped(ti.ndrange(*([3] * dim))):
                            I = base + off
                            if usable(I, lo, hi):
                                if grid_m[I] > 0:
                                    dv = (k * weight(W, off)) * a
                                    grid_v[I] += dv
                                    if ti.static(use_flip):
                                        flip.grid_dv[I] += dv
            if ti.static(dim == 2):
                for i, j in ti.ndrange((lo[0], hi[0]), (lo[1], hi[1])):
                    vm[i, j] = 0.0
            else:
                for i, j, k in ti.ndrange((lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2])):
                    vm[i, j, k] = 0.0

        self._prepare, self._push, self._finish = prepare, push, finish

    def couple(self, dt: float) -> None:
        self.hits[None] = 0
        self._prepare()
        self._push(dt)
        if self.relax is not None and self.hits[None] > 0:  # nothing touched: the set's own step stands
            for _ in range(RELAX):
                self.relax(dt)
                self._push(dt)
        self._finish(dt)
