"""Advection on the MAC grid: semi-Lagrangian (Stam 1999) with an RK3 back-trace and
(bi/tri)linear interpolation, and two less dissipative variants built from it:

* ``maccormack`` (Selle et al. 2008, "An unconditionally stable MacCormack method"):
  q^ = SL(q, dt); q_back = SL(q^, -dt); q_new = q^ + (q - q_back) / 2, clamped to the range of
  the values the first interpolation used (their limiter, clamp variant), so no new extrema appear.
* ``bfecc`` (Kim et al. 2005): q~ = q + (q - SL(SL(q, dt), -dt)) / 2; q_new = SL(q~, dt), with the
  same clamp.

Everything runs in grid coordinates X = (x - origin) / dx (cells, per axis). Every velocity
component and the cell scalars are advected by the velocity at the start of the stage (the
copies are written to scratch fields and copied back at the end): two kernel launches, one for
the node velocities the back-traces interpolate, one for every pass. RK3 is Ralston's third-order
scheme (as in Genesis's smoke demo); its first stage takes the velocity from the faces around the
point.
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sf.boundary import Boundary, make_foreach
from simcli.solvers.sf.grid import Layout

with stdout_to_stderr():
    import taichi as ti


def stagger(layout: Layout, d: int | None) -> list[float]:
    """Sample offsets (in cells) of component d's faces (d None: cell centres)."""
    return [0.0 if a == d else 0.5 for a in range(layout.dim)]


def make_sampling(layout: Layout, f, at):
    """ti.funcs: clamp/wrap a point into the domain, interpolate a component-indexed field, sample
    the velocity."""
    dim, n, periodic = layout.dim, layout.n, layout.periodic
    inv_dx = [1.0 / h for h in layout.dx]

    @ti.func
    def into_domain(X):
        for a in ti.static(range(dim)):
            if ti.static(periodic[a]):
                X[a] -= ti.floor(X[a] / n[a]) * n[a]
            else:
                X[a] = ti.min(ti.max(X[a], 0.0), ti.cast(n[a], f))
        return X

    @ti.func
    def interp(q: ti.template(), k, X, d):
        """Component k of q at grid point X, and the min / max of the 2^dim samples used. d is the
        axis the samples are staggered along (a face component) or -1 (cell centres); valid sample
        indices are 0..n_d along d and -1..n_a (ghosts) along the other axes."""
        base = ti.Vector.zero(ti.i32, dim)
        fr = ti.Vector.zero(f, dim)
        for a in ti.static(range(dim)):
            on = a == d
            g = ti.min(ti.max(X[a] - ti.select(on, 0.0, 0.5), ti.select(on, 0.0, -1.0)), ti.cast(n[a], f))
            b = ti.min(ti.cast(ti.floor(g), ti.i32), n[a] - 1)
            base[a] = b
            fr[a] = g - b
        v = ti.cast(0.0, f)
        vmin = ti.cast(1e30, f)
        vmax = ti.cast(-1e30, f)
        for c in ti.static(ti.grouped(ti.ndrange(*([2] * dim)))):  # unrolled: the hot loop
            w = ti.cast(1.0, f)
            for a in ti.static(range(dim)):
                w *= fr[a] if c[a] == 1 else 1.0 - fr[a]
            sv = q[at(k, base + c)]
            v += w * sv
            vmin = ti.min(vmin, sv)
            vmax = ti.max(vmax, sv)
        return v, vmin, vmax

    def make_velocity(node):
        @ti.func
        def velocity(X):
            """Velocity at grid point X in cells per second, interpolated from the node velocities."""
            base = ti.Vector.zero(ti.i32, dim)
            fr = ti.Vector.zero(f, dim)
            for a in ti.static(range(dim)):
                b = ti.min(ti.cast(ti.floor(X[a]), ti.i32), n[a] - 1)
                base[a] = b
                fr[a] = X[a] - b
            V = ti.Vector.zero(f, dim)
            for c in ti.static(ti.grouped(ti.ndrange(*([2] * dim)))):
                w = ti.cast(1.0, f)
                for a in ti.static(range(dim)):
                    w *= fr[a] if c[a] == 1 else 1.0 - fr[a]
                V += w * node[base + c]
            return V * ti.Vector(inv_dx, f)

        return velocity

    return into_domain, interp, make_velocity


class Advector:
    """Builds the advection kernel for a velocity (component-indexed face field) and cell scalars."""

    def __init__(
        self, layout: Layout, f, boundary: Boundary, vel, scalars, n_scalars: int, scheme: str
    ) -> None:
        self.layout, self.f, self.bc, self.scheme = layout, f, boundary, scheme
        dim = layout.dim
        self.vel, self.scalars, self.n_sc = vel, scalars, n_scalars
        off = (0,) + (-1,) * dim
        face_shape = (dim,) + tuple(c + 3 for c in layout.n)
        cell_shape = (n_scalars,) + tuple(c + 2 for c in layout.n)
        n_tmp = {"semi_lagrangian": 1, "bfecc": 2, "maccormack": 4}[scheme]
        # the velocity at the grid nodes (corners of the cells), for the back-traces: one gather of a
        # vector per corner instead of one per component (3x fewer in 3D)
        self.node = ti.Vector.field(dim, f, shape=tuple(c + 1 for c in layout.n))
        self.dt = ti.field(f, shape=())
        # scratch: one (semi-Lagrangian) or two (bfecc) copies of every advected field; maccormack also
        # keeps the range (min, max) of the first interpolation's samples for its limiter, which
        # saves a third back-trace per point
        self.tmp_vel = [ti.field(f, shape=face_shape, offset=off) for _ in range(n_tmp)]
        self.tmp_sc = [ti.field(f, shape=cell_shape, offset=off) for _ in range(n_tmp)]
        self._make()

    def _make(self) -> None:
        L, f, bc, scheme = self.layout, self.f, self.bc, self.scheme
        dim = L.dim
        vel, sc, n_sc = self.vel, self.scalars, self.n_sc
        tv, ts = self.tmp_vel, self.tmp_sc
        at = bc.at
        into_domain, interp, make_velocity = make_sampling(L, f, at)
        node = self.node
        velocity = make_velocity(node)
        nodes = [(0, c + 1) for c in L.n]
        n_avg = 1.0 / (1 << (dim - 1))

        node_loop = make_foreach(nodes)[0]

        @ti.func
        def node_body(N):
            """Component d at a node: the mean of the 2^(dim-1) faces of d that touch it (ghost faces
            outside the walls carry the wall condition, so a sticky wall's node gets the wall's
            velocity)."""
            V = ti.Vector.zero(f, dim)
            for d in ti.static(range(dim)):
                acc = ti.cast(0.0, f)
                for c in ti.static(ti.grouped(ti.ndrange(*([2] * dim)))):
                    if ti.static(c[d] == 0):
                        acc += vel[at(d, N - c)]
                V[d] = acc * n_avg
            node[N] = V

        @ti.func
        def node_velocity():
            node_loop(node_body)

        cells = bc.cells

        inv_dx = [1.0 / h for h in L.dx]

        @ti.func
        def local_velocity(I, d: ti.template()):
            """Velocity [cells/s] at face I of component d (d = -1: at the centre of cell I) from the faces
            around it: its own value along d, the mean of the 2 (cell) or 4 (face) nearest faces of the other
            components. Exact where the node interpolation would smooth, and a quarter of the gathers."""
            V = ti.Vector.zero(f, dim)
            for a in ti.static(range(dim)):
                if ti.static(a == d):
                    V[a] = vel[at(a, I)] * inv_dx[a]
                elif ti.static(d < 0):
                    J = I
                    J[a] += 1
                    V[a] = 0.5 * (vel[at(a, I)] + vel[at(a, J)]) * inv_dx[a]
                else:
                    acc = ti.cast(0.0, f)
                    for c in ti.static(range(4)):
                        J = I
                        J[a] += c & 1
                        J[d] -= (c >> 1) & 1
                        acc += vel[at(a, J)]
                    V[a] = 0.25 * acc * inv_dx[a]
            return V

        @ti.func
        def trace_from(X, v1, dt):
            """RK3 (Ralston) characteristic through X over -dt, v1 the velocity at X: where the fluid at X
            came from. (Unrolled: as a run-time loop over the stages it runs at half the speed.)"""
            v2 = velocity(into_domain(X - 0.5 * dt * v1))
            v3 = velocity(into_domain(X - 0.75 * dt * v2))
            return into_domain(X - dt * ((2.0 / 9.0) * v1 + (1.0 / 3.0) * v2 + (4.0 / 9.0) * v3))

        face_rng = [bc.face_range(d) for d in range(dim)]

        @ti.func
        def point(I, d: ti.template()):
            """Grid coordinates of face I of component d (d = -1: of cell I)."""
            X = ti.Vector.zero(f, dim)
            for a in ti.static(range(dim)):
                X[a] = I[a] + ti.static(0.0 if a == d else 0.5)
            return X

        @ti.func
        def trace(I, d: ti.template(), dt):
            """Foot of the characteristic through face I of component d (d = -1: cell I) over -dt."""
            return trace_from(point(I, d), local_velocity(I, d), dt)

        # Every pass loops over the faces of each velocity component, then over the cells (smoke
        # density and temperature share a cell's back-trace), with the component fixed at compile
        # time (1.7x faster than one loop over all points with the component as a run-time index)
        # and the last axis as the inner serial loop (make_foreach).
        face_loop = [make_foreach(face_rng[d])[0] for d in range(dim)]
        cell_loop = make_foreach(cells)[0]
        dtf = self.dt

        def sl_pass(src_v, dst_v, src_s, dst_s, lo_v=None, hi_v=None, lo_s=None, hi_s=None):
            """dst = src interpolated at the foot of the characteristic (over -dt); with lo/hi fields,
            also the min / max of the samples used (MacCormack's limiter)."""
            keep = lo_v is not None

            def face(d):
                @ti.func
                def body(I):
                    v, lo, hi = interp(src_v, d, trace(I, d, dtf[None]), d)
                    J = at(d, I)
                    dst_v[J] = v
                    if ti.static(keep):
                        lo_v[J] = lo
                        hi_v[J] = hi

                return body

            @ti.func
            def cell(I):
                Xb = trace(I, -1, dtf[None])
                for k in ti.static(range(n_sc)):
                    v, lo, hi = interp(src_s, k, Xb, -1)
                    K = at(k, I)
                    dst_s[K] = v
                    if ti.static(keep):
                        lo_s[K] = lo
                        hi_s[K] = hi

            return [face(d) for d in range(dim)], cell

        def corrected(hat_v, out_v, hat_s, out_s, lo_v=None, hi_v=None, lo_s=None, hi_s=None):
            """out = q + (q - SL(hat, -dt)) / 2 (BFECC's compensated field, without lo/hi) or
            hat + (q - SL(hat, -dt)) / 2 clamped to [lo, hi] (MacCormack)."""
            clamp = lo_v is not None

            def face(d):
                @ti.func
                def body(I):
                    J = at(d, I)
                    q_back = interp(hat_v, d, trace(I, d, -dtf[None]), d)[0]
                    if ti.static(clamp):
                        out_v[J] = ti.min(ti.max(hat_v[J] + 0.5 * (vel[J] - q_back), lo_v[J]), hi_v[J])
                    else:
                        out_v[J] = vel[J] + 0.5 * (vel[J] - q_back)

                return body

            @ti.func
            def cell(I):
                Xf = trace(I, -1, -dtf[None])
                for k in ti.static(range(n_sc)):
                    K = at(k, I)
                    q_back = interp(hat_s, k, Xf, -1)[0]
                    if ti.static(clamp):
                        out_s[K] = ti.min(ti.max(hat_s[K] + 0.5 * (sc[K] - q_back), lo_s[K]), hi_s[K])
                    else:
                        out_s[K] = sc[K] + 0.5 * (sc[K] - q_back)

            return [face(d) for d in range(dim)], cell

        def bfecc_final(til_v, out_v, til_s, out_s):
            """out = SL(til, dt) clamped to the range of q's samples at the same point."""

            def face(d):
                @ti.func
                def body(I):
                    Xb = trace(I, d, dtf[None])
                    v = interp(til_v, d, Xb, d)[0]
                    _, lo, hi = interp(vel, d, Xb, d)
                    out_v[at(d, I)] = ti.min(ti.max(v, lo), hi)

                return body

            @ti.func
            def cell(I):
                Xb = trace(I, -1, dtf[None])
                for k in ti.static(range(n_sc)):
                    v = interp(til_s, k, Xb, -1)[0]
                    _, lo, hi = interp(sc, k, Xb, -1)
                    out_s[at(k, I)] = ti.min(ti.max(v, lo), hi)

            return [face(d) for d in range(dim)], cell

        @ti.func
        def run(bodies: ti.template()):
            for d in ti.static(range(dim)):
                face_loop[d](bodies[0][d])
            cell_loop(bodies[1])

        @ti.func
        def ghosts(qv: ti.template(), qs: ti.template()):
            bc.fill_face_ghosts(qv)
            bc.fill_cell_ghosts(qs, n_sc)

        def copy_back(src_v, src_s):
            """Bodies: the result into the velocity (fixed faces keep their values) and the scalars."""

            def make(d):
                @ti.func
                def body(I):
                    J = at(d, I)
                    vel[J] = bc.fixed_value(d, I, src_v[J])

                return body

            @ti.func
            def cell(I):
                for k in ti.static(range(n_sc)):
                    sc[at(k, I)] = src_s[at(k, I)]

            return bc.per_component(make), cell

        A_v, A_s = tv[0], ts[0]
        if scheme == "semi_lagrangian":
            stages = [sl_pass(vel, A_v, sc, A_s)]
        elif scheme == "maccormack":
            lo_v, lo_s, hi_v, hi_s = tv[2], ts[2], tv[3], ts[3]
            stages = [
                sl_pass(vel, A_v, sc, A_s, lo_v, hi_v, lo_s, hi_s),
                corrected(A_v, tv[1], A_s, ts[1], lo_v, hi_v, lo_s, hi_s),
            ]
        else:
            stages = [
                sl_pass(vel, A_v, sc, A_s),
                corrected(A_v, tv[1], A_s, ts[1]),
                bfecc_final(tv[1], A_v, ts[1], A_s),
            ]
        result = (tv[1], ts[1]) if scheme == "maccormack" else (A_v, A_s)
        temps = [(A_v, A_s), (tv[1], ts[1])] if len(tv) > 1 else [(A_v, A_s)]

        @ti.kernel
        def node_kernel():
            node_velocity()

        back = copy_back(result[0], result[1])

        @ti.kernel
        def advect_kernel(dt: f):
            dtf[None] = dt
            for i in ti.static(range(len(stages))):
                if ti.static(i > 0):  # the next stage interpolates the previous one's output
                    ghosts(temps[i - 1][0], temps[i - 1][1])
                run(stages[i])
            run(back)
            ghosts(vel, sc)

        self.nodes, self._advect = node_kernel, advect_kernel

    def advect(self, dt: float, nodes_ready: bool = False) -> None:
        """Advect the velocity and the scalars over dt by the current velocity (or, with nodes_ready,
        by the velocity whose node values ``nodes()`` stored last: advection-reflection)."""
        if not nodes_ready:
            self.nodes()
        self._advect(dt)
