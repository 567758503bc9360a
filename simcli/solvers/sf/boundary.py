"""Boundary conditions of the MAC grid as Taichi funcs (called inside the step's kernels), and the
indexing helpers every SF kernel shares.

Storage: the velocity is one field of shape (dim, n_x + 3, ...) (component first, so each
component is contiguous), the face kinds likewise; the cell scalars (smoke density, temperature)
one field (2, n_x + 2, ...). ``at(k, I)`` is the index of component / scalar k at grid index I;
a kernel loops over components at run time, so each interpolation or stencil is compiled once
(Taichi's front end spends time per inlined statement, not per loop trip).

* **Fixed faces** (walls, colliders; see ``grid.py`` for the face kinds): the normal velocity of a
  wall face is the wall's normal velocity (0 for a still wall), of a collider face 0.
* **Ghost layers** make interpolation near a wall see the wall condition: for a tangential
  velocity component the ghost value is ``2 u_wall - u_inner`` on a sticky (no-slip) wall, so that
  the value half-way, on the wall, is the wall's velocity (a moving lid); ``u_inner`` on a slip or
  open face (zero shear); the opposite side's value on a periodic face. Scalars (smoke density,
  temperature) get zero-gradient ghosts, or periodic ones.
* **Periodic faces**: face n_d of component d is face 0 (a duplicate kept in sync).
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sf.grid import SOLID_FACE, W_PERIODIC, W_STICKY, WALL_HI, WALL_LO, Layout

with stdout_to_stderr():
    import taichi as ti


def make_at(dim: int):
    if dim == 2:

        @ti.func
        def at(k, I):
            """Index of component (or scalar) k at grid index I."""
            return ti.Vector([k, I[0], I[1]], ti.i32)
    else:

        @ti.func
        def at(k, I):
            """Index of component (or scalar) k at grid index I."""
            return ti.Vector([k, I[0], I[1], I[2]], ti.i32)

    return at


def make_neighbour(n: tuple, periodic: tuple):
    """``nb(I, a, s)``: grid index I + s e_a (s = +-1), wrapped on a periodic axis (indices 0 .. n_a - 1
    either way) of a grid of ``n`` points."""

    @ti.func
    def nb(I, a: ti.template(), s: ti.template()):
        J = I
        if ti.static(periodic[a]):
            if ti.static(s > 0):
                J[a] = ti.select(J[a] < n[a] - 1, J[a] + 1, 0)
            else:
                J[a] = ti.select(J[a] > 0, J[a] - 1, n[a] - 1)
        else:
            J[a] += s
        return J

    return nb


def make_foreach(rng: list):
    """Loops over the box ``rng`` ((lo, hi) per axis), parallel over the outer axes with the last
    (contiguous) axis as a serial inner loop: a stencil sweep costs a third of the CPU time of a flat
    ``ti.grouped`` loop (measured on 64^3). Returns ti.funcs

    * ``foreach(body)``: body(I) for every index I;
    * ``foreach_sum(body, out, slot)``: adds the bodies' return values into ``out[slot]`` (one atomic
      add per row);
    * ``foreach_sum_max(body, out, s, m, src, k)``: body(I, c) returns (value to sum, value to max);
      ``c = src[k]`` is read once per row (a CG step length: read in the inner loop it is reloaded
      every iteration, since the loop's stores might alias it);
    * ``foreach_scaled(body, src, k)``: body(I, src[k]);
    * ``foreach_sum_scaled(body, out, slot, src, k)``: both.
    """
    lo = [r[0] for r in rng]
    hi = [r[1] for r in rng]
    inner = (lo[-1], hi[-1])
    if len(rng) == 3:
        rows = ((lo[0], hi[0]), (lo[1], hi[1]))

        @ti.func
        def index(i, j, k):
            return ti.Vector([i, j, k])
    else:
        rows = ((lo[0], hi[0]), (0, 1))

        @ti.func
        def index(i, j, k):
            return ti.Vector([i, k])

    @ti.func
    def foreach(body: ti.template()):
        for i, j in ti.ndrange(*rows):
            for k in range(inner[0], inner[1]):
                body(index(i, j, k))

    @ti.func
    def foreach_sum(body: ti.template(), out: ti.template(), slot: ti.template()):
        for i, j in ti.ndrange(*rows):
            acc = ti.cast(0.0, ti.f64)
            for k in range(inner[0], inner[1]):
                acc += body(index(i, j, k))
            out[slot] += acc

    @ti.func
    def foreach_sum_max(
        body: ti.template(),
        out: ti.template(),
        s: ti.template(),
        m: ti.template(),
        src: ti.template(),
        key: ti.template(),
    ):
        for i, j in ti.ndrange(*rows):
            c = src[key]
            acc = ti.cast(0.0, ti.f64)
            mx = ti.cast(0.0, ti.f64)
            for k in range(inner[0], inner[1]):
                a, b = body(index(i, j, k), c)
                acc += a
                mx = ti.max(mx, b)
            out[s] += acc
            ti.atomic_max(out[m], mx)

    @ti.func
    def foreach_scaled(body: ti.template(), src: ti.template(), key: ti.template()):
        for i, j in ti.ndrange(*rows):
            c = src[key]
            for k in range(inner[0], inner[1]):
                body(index(i, j, k), c)

    @ti.func
    def foreach_sum_scaled(
        body: ti.template(), out: ti.template(), slot: ti.template(), src: ti.template(), key: ti.template()
    ):
        for i, j in ti.ndrange(*rows):
            c = src[key]
            acc = ti.cast(0.0, ti.f64)
            for k in range(inner[0], inner[1]):
                acc += body(index(i, j, k), c)
            out[slot] += acc

    return foreach, foreach_sum, foreach_sum_max, foreach_scaled, foreach_sum_scaled


def make_foreach_color(n: tuple):
    """``foreach_color(body, color)``: body(I) for the cells of one colour (sum of I even or odd) of a
    red-black ordering, with the inner loop stepping by 2."""
    if len(n) == 3:

        @ti.func
        def foreach_color(body: ti.template(), color: ti.template()):
            for i, j in ti.ndrange(n[0], n[1]):
                k0 = (i + j + color) & 1
                for kk in range((n[2] - k0 + 1) // 2):
                    body(ti.Vector([i, j, k0 + 2 * kk]))
    else:

        @ti.func
        def foreach_color(body: ti.template(), color: ti.template()):
            for i in range(n[0]):
                k0 = (i + color) & 1
                for kk in range((n[1] - k0 + 1) // 2):
                    body(ti.Vector([i, k0 + 2 * kk]))

    return foreach_color


class Boundary:
    def __init__(self, layout: Layout, kinds, wall_vel, solid_vel=None) -> None:
        self.layout = layout
        self.kinds = kinds  # u8 face kinds, shape (dim, n + 3)
        self.wall_vel = wall_vel  # ti.Vector.field(dim, f, shape=(dim, 2))
        self.solid_vel = solid_vel  # moving colliders (moving.py): each solid face's value, like vel
        self.at = make_at(layout.dim)
        self.cells = [(0, c) for c in layout.n]
        # loops over the faces of one component (nested, contiguous inner axis) and over the cells
        self.face_loops = [make_foreach(self.face_range(d)) for d in range(layout.dim)]
        self.cell_loops = make_foreach(self.cells)
        self._make()

    def face_range(self, d: int, ghosts: bool = False) -> list:
        """ndrange bounds of the faces of component d (with the tangential ghosts if asked)."""
        n = self.layout.n
        g = 1 if ghosts else 0
        return [(0, n[b] + 1) if b == d else (-g, n[b] + g) for b in range(self.layout.dim)]

    def cell_range(self, ghosts: bool = False) -> list:
        g = 1 if ghosts else 0
        return [(-g, c + g) for c in self.layout.n]

    def _make(self) -> None:
        L = self.layout
        dim, n, wall, periodic = L.dim, L.n, L.wall, L.periodic
        kinds, wall_vel, at = self.kinds, self.wall_vel, self.at
        solid_vel = self.solid_vel
        moving = solid_vel is not None

        # ghost loops: every face (or cell) with the index along the ghost axis pinned to 0
        dup_rng, ghost_rng, cell_rng = [], [], []
        for d in range(dim):
            r = self.face_range(d, ghosts=True)
            r[d] = (0, 1)
            dup_rng.append(r)
            row = []
            for a in range(dim):
                r = self.face_range(d, ghosts=True)
                r[a] = (0, 1)
                row.append(r)
            ghost_rng.append(row)
        for a in range(dim):
            r = self.cell_range(ghosts=True)
            r[a] = (0, 1)
            cell_rng.append(r)

        @ti.func
        def fixed_value(d, I, current):
            """The prescribed value of face I of component d if it is fixed, else ``current``."""
            k = kinds[at(d, I)]
            v = current
            if k == SOLID_FACE:
                v = 0.0
                if ti.static(moving):  # a moving collider's surface velocity (moving.py)
                    v = solid_vel[at(d, I)]
            elif k == WALL_LO:
                v = wall_vel[d, 0][d]
            elif k == WALL_HI:
                v = wall_vel[d, 1][d]
            return v

        face_loop = [fl[0] for fl in self.face_loops]

        @ti.func
        def each_face(bodies: ti.template()):
            """bodies[d](I) for every face I of every component d (d fixed at compile time)."""
            for d in ti.static(range(dim)):
                face_loop[d](bodies[d])

        def per_component(make_body):
            """[make_body(0), ..., make_body(dim - 1)]: the bodies ``each_face`` takes."""
            return [make_body(d) for d in range(dim)]

        def set_fixed(q):
            """Bodies for ``each_face``: fixed faces of q get their prescribed values."""

            def make(d):
                @ti.func
                def body(I):
                    J = at(d, I)
                    q[J] = fixed_value(d, I, q[J])

                return body

            return per_component(make)

        @ti.func
        def ghost_index(I, a: ti.template(), s: ti.template(), periodic_src: ti.template()):
            """(ghost, source) indices of side s (0 lower, 1 upper) along axis a: the source is the
            wrapped cell of a periodic axis or the first inner one."""
            G = I
            src = I
            if ti.static(s == 0):
                G[a] = -1
                if ti.static(periodic_src):
                    src[a] = n[a] - 1
                else:
                    src[a] = 0
            else:
                G[a] = n[a]
                if ti.static(periodic_src):
                    src[a] = 0
                else:
                    src[a] = n[a] - 1
            return G, src

        @ti.func
        def fill_face_ghosts(q: ti.template()):
            for d in ti.static(range(dim)):
                if ti.static(periodic[d]):
                    for I in ti.grouped(ti.ndrange(*dup_rng[d])):
                        J = I
                        J[d] = n[d]
                        q[at(d, J)] = q[at(d, I)]
                for a in ti.static(range(dim)):
                    if ti.static(a != d):
                        for I in ti.grouped(ti.ndrange(*ghost_rng[d][a])):
                            for s in ti.static(range(2)):
                                G, src = ghost_index(I, a, s, periodic[a])
                                if ti.static(wall[a][s] == W_STICKY and not periodic[a]):
                                    q[at(d, G)] = 2.0 * wall_vel[a, s][d] - q[at(d, src)]
                                else:
                                    q[at(d, G)] = q[at(d, src)]

        @ti.func
        def fill_cell_ghosts(q: ti.template(), nk: ti.template()):
            for a in ti.static(range(dim)):
                for I in ti.grouped(ti.ndrange(*cell_rng[a])):
                    for s in ti.static(range(2)):
                        G, src = ghost_index(I, a, s, wall[a][s] == W_PERIODIC)
                        for k in range(nk):
                            q[at(k, G)] = q[at(k, src)]

        self.each_face, self.per_component = each_face, per_component
        self.fixed_value = fixed_value
        self.set_fixed = set_fixed
        self.fill_face_ghosts = fill_face_ghosts
        self.fill_cell_ghosts = fill_cell_ghosts
