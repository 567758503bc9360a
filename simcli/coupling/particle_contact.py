"""Two-way contact between two particle families without an MPM grid: SPH <-> PBD, SPH <-> FEM, PBD <-> FEM.

The same multi-material contact as grid_contact.py (Bardenhagen, Brackbill & Sulsky 2000), on a grid of the
pair's own: both sets' masses and momenta are splatted onto a background grid with quadratic B-spline weights
(a P2G of each set), and at each node holding both, where they approach along the contact normal, the normal
components of both nodal velocities are replaced by the pair's centre-of-mass normal velocity; tangential
velocities are kept (free slip). Each particle receives its node's velocity change with the same weights (a
FLIP increment), positions advanced already (PBD, FEM) are moved by dt times it. Per node, with masses m, M,
velocities v (set a), u (set b) and unit normal n from a into b:

    contact if  m > 0, M > 0  and  (v - u) . n > 0
    v_cm = (m v + M u) / (m + M);  dv = -((v - v_cm) . n) n;  du = -((u - v_cm) . n) n

m dv + M du = 0 at every node and the weights sum to one, so momentum is conserved exactly; an inelastic merge
of normal velocities, interpolated back with convex weights, never adds kinetic energy. The normal is
grad(phi_b - phi_a) by central differences, phi a set's volume fraction (splatted mass / (density dx^dim));
a set without volume (cloth, rope: rho None) leaves only the other's term. Where both sets carry a volume and
their fractions at a node sum above 1 + tol, the set named by ``shift`` is moved out along the normal by
SEPARATION x the excess x dx per substep (positions only: the overlap correction of grid_contact.py).

The grid: cell ``dx`` = the coarser set's particle spacing (each node then sees particles of both sets within
1.5 cells, the B-spline's reach; the two stay about a cell apart), over the scene's domain with two cells of
margin, sparse (pointer blocks of BLOCK^dim nodes allocated where particles splat, freed after each substep:
memory and the node loops scale with the bodies, not the domain); one kernel launch per substep (two
scatters, a node pass, two gathers, a clear) and the blocks' release. Nodes on the grid's border are never in
contact (each family keeps its own walls).
"""

import math

import taichi as ti

from simcli.coupling.grid_contact import OVERLAP_TOL, SEPARATION, ParticleSet
from simcli.errors import SimcliError


def _check_snode_room(name: str) -> None:
    """A sparse tree numbered past Taichi's SNode limit would write beyond its runtime's per-SNode arrays
    (silent memory corruption, simcli.backend.reset_taichi): refused with a message instead."""
    from simcli.backend import MAX_SNODES, next_snode_id

    first = next_snode_id()
    if first + 16 > MAX_SNODES:  # (the tree itself: root, pointer, dense, up to 5 fields of <= 3 components)
        raise SimcliError(
            f"coupling {name}: the scene's fields already use {first} of Taichi's {MAX_SNODES} SNodes and "
            "the contact grid would be numbered past them (Taichi would write beyond its runtime's arrays). "
            "Run fewer entities, probes or emitters in one scene"
        )


BLOCK = 4  # nodes per side of the sparse grid's blocks


class ParticleContact:
    """A pair of particle sets in contact on a background grid of cell ``dx`` over the box [lo, hi]."""

    def __init__(
        self, name: str, dim: int = 3, precision: str = "f32", lo=(), hi=(), dx: float = 0.0
    ) -> None:
        self.name = name
        self.configure(dim, precision, lo, hi, dx)
        self.a: "ParticleSet | None" = None
        self.b: "ParticleSet | None" = None
        self.shift: "str | None" = None  # "a", "b" or None: which set the overlap correction moves

    def configure(self, dim: int, precision: str, lo, hi, dx: float) -> None:
        self.dim, self.precision = dim, precision
        self.lo, self.hi, self.dx = [float(c) for c in lo], [float(c) for c in hi], float(dx)

    def build(self) -> None:
        a, b, dim = self.a, self.b, self.dim
        assert a is not None and b is not None
        f = ti.f64 if self.precision == "f64" else ti.f32
        dx = self.dx
        inv_dx = 1.0 / dx
        origin = [c - 2.0 * dx for c in self.lo]
        shape = tuple(int(math.ceil((h - l) * inv_dx)) + 5 for l, h in zip(self.lo, self.hi))  # noqa: E741
        self.shape = shape
        # sparse: blocks of BLOCK^dim nodes, allocated where a particle splats (a domain much larger than the
        # bodies costs nothing), every loop over the grid runs over the active blocks only
        nblk = [int(math.ceil(s / BLOCK)) for s in shape]
        axes = ti.ij if dim == 2 else ti.ijk
        _check_snode_room(self.name)
        self.blocks = ti.root.pointer(axes, nblk)
        cells = self.blocks.dense(axes, BLOCK)
        self.ma, self.mb = ti.field(f), ti.field(f)
        self.pa = ti.Vector.field(dim, f)  # momentum of a, then its velocity change
        self.pb = ti.Vector.field(dim, f)
        cells.place(self.ma, self.mb, self.pa, self.pb)
        shifted = {"a": a, "b": b}.get(self.shift) if self.shift else None
        sep = shifted is not None and a.rho is not None and b.rho is not None and shifted.shift_x is not None
        self.px = ti.Vector.field(dim, f) if sep else None
        if sep:
            cells.place(self.px)
        # per active node (the blocks the two sets touch); the full grid's count for the record
        self.node_bytes = (2 + 2 * dim + (dim if sep else 0)) * (8 if f == ti.f64 else 4)
        self.bytes = 0  # allocated on the fly per active block: nothing fixed per particle or per domain
        ma, mb, pa, pb, px = self.ma, self.mb, self.pa, self.pb, self.px
        cell = dx**dim
        use_a, use_b = a.rho is not None, b.rho is not None
        if not (use_a or use_b):
            raise ValueError(f"{self.name}: at least one of the two sets needs a volume (density)")
        inv_va = 1.0 / (float(a.rho) * cell) if use_a else 0.0
        inv_vb = 1.0 / (float(b.rho) * cell) if use_b else 0.0
        tol = OVERLAP_TOL
        if sep and shifted.overlap_tol is not None:
            tol = float(shifted.overlap_tol)
        sep_dx = SEPARATION * dx
        shift_a = sep and self.shift == "a"
        shift_b = sep and self.shift == "b"
        org = ti.Vector(origin, dt=f)
        base_max = ti.Vector([s - 3 for s in shape])
        hi_node = ti.Vector([s - 1 for s in shape])
        eps = 1e-12

        def count_of(s: ParticleSet):
            if s.count is not None:
                return s.count
            n = s.n

            @ti.func
            def count():
                return n

            return count

        Na, Nb = count_of(a), count_of(b)
        pos_a, mass_a, vel_a, mvx_a, shx_a = a.pos, a.mass, a.vel, a.move_x, a.shift_x
        pos_b, mass_b, vel_b, mvx_b, shx_b = b.pos, b.mass, b.vel, b.move_x, b.shift_x
        has_mva, has_mvb = mvx_a is not None, mvx_b is not None

        @ti.func
        def weights(xp):
            Xp = (xp - org) * inv_dx
            base = ti.min(ti.max(ti.cast(Xp - 0.5, ti.i32), 0), base_max)
            fx = Xp - ti.cast(base, f)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            return base, w

        @ti.func
        def phi_diff(I):
            r = ti.cast(0.0, f)
            if ti.static(use_b):
                r += mb[I] * inv_vb
            if ti.static(use_a):
                r -= ma[I] * inv_va
            return r

        @ti.func
        def node(I):
            m, M = ma[I], mb[I]
            dv = ti.Vector.zero(f, dim)
            du = ti.Vector.zero(f, dim)
            if ti.static(sep):
                px[I] = ti.Vector.zero(f, dim)
            interior = True
            for d in ti.static(range(dim)):
                interior = interior and 0 < I[d] and I[d] < hi_node[d]
            if m > 0 and M > 0 and interior:
                g = ti.Vector.zero(f, dim)
                for d in ti.static(range(dim)):
                    e = ti.Vector.unit(dim, d, ti.i32)
                    g[d] = phi_diff(I + e) - phi_diff(I - e)
                gn = g.norm()
                if gn > eps:
                    nrm = g / gn
                    if ti.static(sep):
                        over = m * inv_va + M * inv_vb - (1.0 + tol)
                        if over > 0:
                            px[I] = (sep_dx * ti.min(over, 1.0)) * nrm
                    v = pa[I] / m
                    u = pb[I] / M
                    if (v - u).dot(nrm) > 0:
                        vcm = (m * v + M * u) / (m + M)
                        dv = -((v - vcm).dot(nrm)) * nrm
                        du = -((u - vcm).dot(nrm)) * nrm
            pa[I] = dv
            pb[I] = du

        @ti.kernel
        def couple(dt: f):
            for p in range(Na()):  # P2G of a
                mp = mass_a(p)
                if mp > 0:
                    base, w = weights(pos_a(p))
                    vp = vel_a[p]
                    mv = ti.Vector([vp[d] for d in ti.static(range(dim))]) * mp
                    for off in ti.static(ti.grouped(ti.ndrange(*([3] * dim)))):
                        wt = ti.cast(1.0, f)
                        for d in ti.static(range(dim)):
                            wt *= w[off[d]][d]
                        ma[base + off] += wt * mp
                        pa[base + off] += wt * mv
            for p in range(Nb()):  # P2G of b
                mp = mass_b(p)
                if mp > 0:
                    base, w = weights(pos_b(p))
                    vp = vel_b[p]
                    mv = ti.Vector([vp[d] for d in ti.static(range(dim))]) * mp
                    for off in ti.static(ti.grouped(ti.ndrange(*([3] * dim)))):
                        wt = ti.cast(1.0, f)
                        for d in ti.static(range(dim)):
                            wt *= w[off[d]][d]
                        mb[base + off] += wt * mp
                        pb[base + off] += wt * mv
            for I in ti.grouped(ma):  # contact; pa, pb become the velocity changes
                node(I)
            for p in range(Na()):
                mp = mass_a(p)
                if mp > 0:
                    base, w = weights(pos_a(p))
                    dvp = ti.Vector.zero(f, dim)
                    dxp = ti.Vector.zero(f, dim)
                    for off in ti.static(ti.grouped(ti.ndrange(*([3] * dim)))):
                        wt = ti.cast(1.0, f)
                        for d in ti.static(range(dim)):
                            wt *= w[off[d]][d]
                        dvp += wt * pa[base + off]
                        if ti.static(shift_a):
                            dxp -= wt * px[base + off]
                    for d in ti.static(range(dim)):
                        vel_a[p][d] += dvp[d]
                        if ti.static(has_mva):
                            mvx_a[p][d] += dt * dvp[d]
                        if ti.static(shift_a):
                            shx_a[p][d] += dxp[d]
            for p in range(Nb()):
                mp = mass_b(p)
                if mp > 0:
                    base, w = weights(pos_b(p))
                    dup = ti.Vector.zero(f, dim)
                    dxp = ti.Vector.zero(f, dim)
                    for off in ti.static(ti.grouped(ti.ndrange(*([3] * dim)))):
                        wt = ti.cast(1.0, f)
                        for d in ti.static(range(dim)):
                            wt *= w[off[d]][d]
                        dup += wt * pb[base + off]
                        if ti.static(shift_b):
                            dxp += wt * px[base + off]
                    for d in ti.static(range(dim)):
                        vel_b[p][d] += dup[d]
                        if ti.static(has_mvb):
                            mvx_b[p][d] += dt * dup[d]
                        if ti.static(shift_b):
                            shx_b[p][d] += dxp[d]
            for I in ti.grouped(ma):
                ma[I] = 0.0
                mb[I] = 0.0
                pa[I] = ti.Vector.zero(f, dim)
                pb[I] = ti.Vector.zero(f, dim)
                if ti.static(sep):
                    px[I] = ti.Vector.zero(f, dim)

        self._couple = couple

    def couple(self, dt: float) -> None:
        self._couple(dt)
        self.blocks.deactivate_all()  # the next substep allocates where the particles are then
