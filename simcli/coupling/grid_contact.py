"""Two-way contact between the MPM grid and another family's particles (docs/COUPLING.md).

The multi-material contact of Bardenhagen, Brackbill & Sulsky (2000, "The material-point method for granular
materials", CMAME 187) with the other family as the second material: its particles' mass and momentum are
splatted onto the MPM grid with MPM's own quadratic B-spline weights (a P2G of the other set), and at each
node where both materials are present, touch and approach each other along the contact normal, the normal
components of both nodal velocities are replaced by the pair's centre-of-mass normal velocity; tangential
velocities are kept (free slip). The other particles receive their node's velocity change back with the same
weights (a FLIP increment), the MPM node keeps its own; MPM's G2P carries it to its particles.

Per node i with MPM mass m, other mass M, velocities v (MPM) and u (other), unit normal n from MPM to the
other material:

    contact if  m > 0, M > 0  and  (v - u) . n > 0
    v_cm = (m v + M u) / (m + M);  dv = -((v - v_cm) . n) n;  du = -((u - v_cm) . n) n

so m dv + M du = 0: momentum is conserved exactly (sum_p m_p sum_i w_ip du_i = sum_i M_i du_i), and the
normal velocities of the two are merged inelastically, which never adds kinetic energy (and the transfer of
du back to the particles adds none either, by the convexity of the weights). The merge is weighted by the
nodal masses, so where the B-spline tails of the two barely overlap (a node with little of either) it barely
acts: the contact stiffens as the materials meet. The normal is the gradient of phi_other - phi_MPM by
central differences on the grid, phi a material's volume fraction at the node (its particles' volumes
splatted with the same weights, MPM's current J V0, the other's mass / density, over dx^dim): the average of
both materials' normals (Nairn 2013). A set without a meaningful volume
(cloth, rope) passes ``rho = None``: the normal is MPM's own, -grad phi_MPM.

Nodes on or outside the domain faces keep MPM's wall condition (they are not touched). One kernel launch per
substep: scatter the other set, MPM's volumes, node pass over MPM's node box, gather, clear (five parallel
loops).
"""

from dataclasses import dataclass
from typing import Any

import numpy as np
import taichi as ti


@dataclass
class ParticleSet:
    """What the contact reads and edits of the other family's particles (Taichi fields and funcs)."""

    n: int
    pos: Any  # ti.func (i) -> position, MPM's dim components, at the substep's start
    mass: Any  # ti.func (i) -> mass [kg] (0: not coupled, e.g. a pinned vertex)
    vel: Any  # vector field of the velocity the coupling edits (the substep's end velocity)
    vel_dim: int  # its components (the scene's dim)
    rho: Any  # float or None: density for the volume fraction in the normal [kg/m^dim]; None: MPM's normal
    move_x: Any = None  # positions already advanced by vel over dt (PBD): moved by dt du too
    shift_x: Any = None  # positions the overlap correction moves (SPH's before advect, PBD's after)
    count: Any = None  # ti.func () -> the particles in the simulation (emitters, sinks); None: n
    overlap_tol: Any = None  # the overlap correction's tolerance for this set; None: OVERLAP_TOL


# Overlap correction: where the two volume fractions at a node sum to more than 1 + OVERLAP_TOL (the materials
# overlap), the other set's particles are moved out along the normal by SEPARATION x the excess x dx per
# substep (positions only: momentum and kinetic energy are untouched). Without it a liquid resting on an MPM
# body creeps into it by more than a particle spacing over a second (the velocity condition acts on the grid's
# smoothed fields) and a floating block rides about 5% too deep; with no tolerance it pushes the liquid's
# interface layer, which SPH compresses (a free surface to it), a spacing away and the block rides 8-10% too
# high. Chosen on coupling_float_2d (docs/COUPLING.md: the table of the alternatives tried); its verify
# case measures -4.4% with these.
SEPARATION = 0.05
OVERLAP_TOL = 0.3


def pbd_vertex_mass(pbd: Any):
    """A ti.func i -> PBD particle i's mass, 1 / w (0 for a pinned particle, w = 0)."""
    w, f = pbd.w, pbd.f

    @ti.func
    def m(i):
        r = ti.cast(0.0, f)
        if w[i] > 0:
            r = 1.0 / w[i]
        return r

    return m


class GridContact:
    def __init__(self, mpm: Any, other: ParticleSet, name: str) -> None:
        self.mpm, self.other, self.name = mpm, other, name

    def build(self) -> None:
        mpm, o = self.mpm, self.other
        dim, f = mpm.dim, mpm.f
        shape = mpm.grid_shape
        self.ms = ti.field(f, shape=shape)  # the other set's node mass
        self.vm = ti.field(f, shape=shape)  # MPM's node volume (splatted here: MPM's grid keeps none)
        self.pm = ti.Vector.field(dim, f, shape=shape)  # its node momentum, then its node velocity change
        sep = o.rho is not None and o.shift_x is not None
        self.px = ti.Vector.field(dim, f, shape=shape) if sep else None  # node overlap correction [m]
        self.bytes = (
            int(np.prod(shape)) * (dim + 2 + (dim if sep else 0)) * (8 if mpm.precision == "f64" else 4)
        )

        ms, pm, px = self.ms, self.pm, self.px
        shift_x = o.shift_x
        sep_dx = SEPARATION * float(mpm.dx)
        tol = OVERLAP_TOL if o.overlap_tol is None else float(o.overlap_tol)
        grid_v, grid_m, bbox_all = mpm.grid_v, mpm.grid_m, mpm.bbox_all
        flip = mpm.flip
        use_flip = flip is not None
        origin = ti.Vector(list(mpm.origin), dt=f)
        inv_dx = float(mpm.inv_dx)
        base_max = ti.Vector([s - 3 for s in shape])
        lo_node = ti.Vector(list(mpm.lo_node))
        hi_node = ti.Vector(list(mpm.hi_node))
        cell = mpm.dx**dim
        inv_cell = 1.0 / cell  # phi_MPM = (sum_p w_ip J_p V0_p) / dx^dim: volumes, so that materials of any
        # density on MPM's grid (a light jelly, heavy sand) count by the space they fill
        vm = self.vm
        mx, mF, mvol = mpm.x, mpm.F, mpm.vol
        use_phi = o.rho is not None
        inv_vo = 1.0 / (float(o.rho) * cell) if use_phi else 0.0
        pos, mass, vel, move_x = o.pos, o.mass, o.vel, o.move_x  # vel may have more components (PBD: 3)
        has_move = move_x is not None
        n = o.n
        N = o.count  # the active count of a family with emitters or sinks
        if N is None:

            @ti.func
            def N():
                return n

        NM = mpm.count  # MPM's active count (its constant n without emitters or sinks)
        eps = 1e-12

        @ti.func
        def base_of(xp):
            Xp = (xp - origin) * inv_dx
            return ti.min(ti.max(ti.cast(Xp - 0.5, ti.i32), 0), base_max)

        @ti.func
        def weights(xp):
            Xp = (xp - origin) * inv_dx
            base = ti.min(ti.max(ti.cast(Xp - 0.5, ti.i32), 0), base_max)
            fx = Xp - ti.cast(base, f)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            return base, w

        @ti.func
        def in_box(I, lo, hi):
            ok = True
            for d in ti.static(range(dim)):
                ok = ok and lo[d] <= I[d] and I[d] < hi[d]
            return ok

        @ti.func
        def touches_box(base, lo, hi):
            """Whether any node of the 3^dim stencil at base lies in [lo, hi): the other set's particles far
            from MPM's node box (most of a large liquid) skip the weights and the 3^dim node tests."""
            ok = True
            for d in ti.static(range(dim)):
                ok = ok and base[d] + 2 >= lo[d] and base[d] < hi[d]
            return ok

        @ti.func
        def phi_diff(I, lo, hi):
            """phi_other - phi_MPM at node I (-phi_MPM for a set without volume; 0 outside MPM's node box,
            where grid_m is stale)."""
            r = ti.cast(0.0, f)
            if in_box(I, lo, hi):
                r = -vm[I] * inv_cell
                if ti.static(use_phi):
                    r += ms[I] * inv_vo
            return r

        @ti.func
        def node(I, lo, hi):
            M = ms[I]
            du = ti.Vector.zero(f, dim)
            if ti.static(sep):
                px[I] = ti.Vector.zero(f, dim)
            if M > 0:
                m = grid_m[I]
                interior = True
                for d in ti.static(range(dim)):
                    interior = interior and lo_node[d] < I[d] and I[d] < hi_node[d]
                if m > 0 and interior:
                    g = ti.Vector.zero(f, dim)
                    for d in ti.static(range(dim)):
                        e = ti.Vector.unit(dim, d, ti.i32)
                        g[d] = phi_diff(I + e, lo, hi) - phi_diff(I - e, lo, hi)
                    gn = g.norm()
                    if gn > eps:
                        nrm = g / gn
                        if ti.static(sep):
                            over = vm[I] * inv_cell + M * inv_vo - (1.0 + tol)
                            if over > 0:
                                px[I] = (sep_dx * ti.min(over, 1.0)) * nrm
                        v = grid_v[I]
                        u = pm[I] / M
                        if (v - u).dot(nrm) > 0:
                            vcm = (m * v + M * u) / (m + M)
                            dv = -((v - vcm).dot(nrm)) * nrm
                            du = -((u - vcm).dot(nrm)) * nrm
                            grid_v[I] = v + dv
                            if ti.static(use_flip):
                                flip.grid_dv[I] += dv
            return du

        @ti.kernel
        def couple(dt: f):
            lo = bbox_all[0]
            hi = bbox_all[1]
            for p in range(N()):  # the other set's P2G, only onto MPM's node box
                mp = mass(p)
                xp = pos(p)
                if mp > 0 and touches_box(base_of(xp), lo, hi):
                    base, w = weights(xp)
                    vp = vel[p]
                    mv = ti.Vector([vp[d] for d in ti.static(range(dim))]) * mp
                    for off in ti.static(ti.grouped(ti.ndrange(*([3] * dim)))):
                        I = base + off
                        if in_box(I, lo, hi):
                            wt = ti.cast(1.0, f)
                            for d in ti.static(range(dim)):
                                wt *= w[off[d]][d]
                            ms[I] += wt * mp
                            pm[I] += wt * mv
            for p in range(NM()):  # MPM's volumes (current: J V0) onto its own node box
                base, w = weights(mx[p])
                Vp = mvol[p] * (ti.Matrix.identity(f, dim) + mF[p]).determinant()  # F stores H = F - I
                for off in ti.static(ti.grouped(ti.ndrange(*([3] * dim)))):
                    I = base + off
                    if in_box(I, lo, hi):
                        wt = ti.cast(1.0, f)
                        for d in ti.static(range(dim)):
                            wt *= w[off[d]][d]
                        vm[I] += wt * Vp
            if ti.static(dim == 2):  # contact at each node; pm becomes the other set's velocity change
                for i, j in ti.ndrange((lo[0], hi[0]), (lo[1], hi[1])):
                    I = ti.Vector([i, j])
                    pm[I] = node(I, lo, hi)
            else:
                for i, j, k in ti.ndrange((lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2])):
                    I = ti.Vector([i, j, k])
                    pm[I] = node(I, lo, hi)
            for p in range(N()):  # the velocity change back to the particles (G2P of du)
                mp = mass(p)
                xp = pos(p)
                if mp > 0 and touches_box(base_of(xp), lo, hi):  # (elsewhere du and dx are zero)
                    base, w = weights(xp)
                    du = ti.Vector.zero(f, dim)
                    dx = ti.Vector.zero(f, dim)
                    for off in ti.static(ti.grouped(ti.ndrange(*([3] * dim)))):
                        I = base + off
                        if in_box(I, lo, hi):
                            wt = ti.cast(1.0, f)
                            for d in ti.static(range(dim)):
                                wt *= w[off[d]][d]
                            du += wt * pm[I]
                            if ti.static(sep):
                                dx += wt * px[I]
                    for d in ti.static(range(dim)):
                        vel[p][d] += du[d]
                        if ti.static(has_move):
                            move_x[p][d] += dt * du[d]
                        if ti.static(sep):
                            shift_x[p][d] += dx[d]
            if ti.static(dim == 2):
                for i, j in ti.ndrange((lo[0], hi[0]), (lo[1], hi[1])):
                    ms[i, j] = 0.0
                    vm[i, j] = 0.0
                    pm[i, j] = ti.Vector.zero(f, dim)
                    if ti.static(sep):
                        px[i, j] = ti.Vector.zero(f, dim)
            else:
                for i, j, k in ti.ndrange((lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2])):
                    ms[i, j, k] = 0.0
                    vm[i, j, k] = 0.0
                    pm[i, j, k] = ti.Vector.zero(f, dim)
                    if ti.static(sep):
                        px[i, j, k] = ti.Vector.zero(f, dim)

        self._couple = couple

    def couple(self, dt: float) -> None:
        self._couple(dt)
