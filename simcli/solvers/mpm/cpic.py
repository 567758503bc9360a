"""Compatible Particle-In-Cell (CPIC; Hu, Fang, Ge, Qu, Zhu, Pradhana, Jiang 2018, "A moving least squares
material point method with displacement discontinuity and two-way rigid body coupling", section 5) for
thin colliders: a collider key ``cpic: true`` (Plane and Box colliders of MPM scenes), and free thin plates:
the same key on a Box rigid body (``rigid_bodies``; docs/RIGID.md, CPIC bodies), which is a moving named
collider whose pose the rigid world integrates and whose load (below) is the impulse that moves it.

A particle and a grid node whose segment crosses a CPIC collider are *incompatible*:

* P2G: the particle sends that node nothing; what it would have sent (mass, momentum, stress impulse)
  goes into the node's ``dim + 1`` *ghost* channels (``ghost``): seen from the particle's side the node
  is inside the wall, and its ghost channels hold that side's material as a thick wall's nodes would;
* G2P: the node gives the particle its ghost node's velocity (``node_velocity``: ghost momentum / mass,
  gravity, then the collider's contact condition with the normal towards the particle's side), to the
  velocity and to the APIC gradient C alike, summed in one run-time loop after the stencil
  (``ghost_sum``). The paper's ghost velocity, the particle's own less its approach to the collider,
  ``v_g = v_p - min(0, (v_p - v_r) . n) n``, is used only where a ghost node holds no mass: with it
  alone a liquid next to a thin wall compacted onto it (docs/MPM.md, CPIC);
* the collider's contact condition also acts on the nodes less than half a cell in front of its broad
  faces (boundary.GridBoundary: ``CPIC_REACH``, ``_cpic_face``);
* after advection a particle that ended inside a thin Box, or whose path crossed its mid-plane, goes onto
  the broad face of the side it started from, its velocity into the plate removed (``keep_side``; the
  paper's penalty force is not used).

So material on one side of a plate thinner than the kernel's support (1.5 cells each side) neither gives
to nor takes from the nodes on the other side: it is not dragged across, and a plate cuts cleanly.

Crossing: a Box is treated as a plate along its thinnest axis (body frame): the segment crosses it where
its mid-plane lies between the two points and the crossing point lies within the Box's extent along the
other axes. A Plane: the two points lie on opposite sides of it. Both in the collider's body frame at the
start of the substep (``set_time``): the particles' positions are those of the start too.

Force on a named CPIC collider: momentum is exchanged with it only through the incompatible pairs, so its
load is computed exactly from them: what a particle did not send (``sum_excl w_i (m v + Q (x_i - x_p))``)
less what it took back from the ghost nodes (``m sum_excl w_i v_i``), plus what the non-crossing
projection removed (and, as for every collider, the node band's momentum change). Attributed to the
particle's first CPIC collider that makes any of its nodes incompatible.

What is compiled: one run-time loop over the CPIC colliders (their geometry, kind and pose are fields),
only when a scene has one (``n == 0``: nothing of this module is compiled in, every other scene is bit for
bit the same). Under FLIP (transfer: flip) the FLIP increment would be gathered from all nodes: the scene
check refuses cpic with it.
"""

from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti

KINDS = ("Plane", "Box")


def cpic_indices(scene: Any) -> list[int]:
    """Indices (in boundary.GridBoundary.colliders order: the scene's colliders first, then its rigid bodies,
    simcli.colliders.collider_specs) of the CPIC ones: colliders and rigid bodies with ``cpic: true``."""
    out = [k for k, c in enumerate(scene.colliders) if getattr(c, "cpic", False)]
    nc = len(scene.colliders)
    out += [
        nc + k for k, b in enumerate(getattr(scene, "rigid_bodies", None) or []) if getattr(b, "cpic", False)
    ]
    return out


@ti.data_oriented
class CPIC:
    """The CPIC colliders of an MPM solver and the per-particle pieces P2G and G2P call."""

    def __init__(self, boundary: Any, scene: Any, dim: int, dtype: Any, origin, dx: float) -> None:
        self.dim, self.f = dim, dtype
        self.dx = float(dx)
        self.origin = tuple(float(o) for o in origin)
        self.idx = cpic_indices(scene)
        self.n = len(self.idx)
        self.boundary = boundary
        self.specs = [boundary.colliders[k] for k in self.idx]
        self.motions = [boundary.poses.motions[k] for k in self.idx]
        for s in self.specs:
            if s.kind not in KINDS:
                raise ValueError(f"cpic: true is for Plane and Box colliders, not {s.kind}")
        self.any_moving = any(m is not None for m in self.motions)
        self.any_named = any(s.name is not None for s in self.specs)
        # a Box is a plate along its thinnest axis
        self.axis = []
        for s in self.specs:
            a = 0
            if s.kind == "Box":
                a = int(np.argmin(np.asarray(s.b, float) - np.asarray(s.a, float)))
            self.axis.append(a)

    def allocate(self) -> None:
        dim, f, nc = self.dim, self.f, max(1, self.n)
        self.kind = ti.field(ti.i32, shape=nc)  # 0 Plane, 1 Box
        self.k = ti.field(ti.i32, shape=nc)  # index among the boundary's colliders (loads)
        self.named = ti.field(ti.i32, shape=nc)
        self.contact = ti.field(ti.i32, shape=nc)  # 0 slip, 1 sticky, 2 separate
        self.mu = ti.field(f, shape=nc)
        self.thin = ti.field(ti.i32, shape=nc)  # Box: its thin axis
        self.centre = ti.Vector.field(dim, f, shape=nc)  # Box centre / Plane point (body frame)
        self.half = ti.Vector.field(dim, f, shape=nc)  # Box half extents / Plane normal (body frame)
        # pose per slot (0: start of the substep, 1: its end): R (row-major), moving pivot c, pivot p, v, w
        self.pose = ti.field(f, shape=(2, nc, 18))
        npf = np.float64 if f == ti.f64 else np.float32
        kind = np.zeros(nc, np.int32)
        kk = np.zeros(nc, np.int32)
        named = np.zeros(nc, np.int32)
        thin = np.zeros(nc, np.int32)
        cen = np.zeros((nc, dim), npf)
        half = np.zeros((nc, dim), npf)
        for j, s in enumerate(self.specs):
            kind[j] = KINDS.index(s.kind)
            kk[j] = self.idx[j]
            named[j] = int(s.name is not None)
            thin[j] = self.axis[j]
            a, b = np.asarray(s.a, float), np.asarray(s.b, float)
            if s.kind == "Box":
                cen[j], half[j] = 0.5 * (a + b), 0.5 * (b - a)
            else:
                cen[j], half[j] = a, b
        self.kind.from_numpy(kind)
        self.contact.from_numpy(
            np.array(
                [("slip", "sticky", "separate").index(s.contact) for s in self.specs] + [0] * (nc - self.n),
                np.int32,
            )
        )
        self.mu.from_numpy(np.array([s.friction for s in self.specs] + [0.0] * (nc - self.n), npf))
        self.k.from_numpy(kk)
        self.named.from_numpy(named)
        self.thin.from_numpy(thin)
        self.centre.from_numpy(cen)
        self.half.from_numpy(half)
        self.vel = ti.Vector.field(dim, f, shape=(2, nc))  # velocity of the moving pivot per slot
        self._buf = np.zeros((2, nc, 18), npf)
        self._vbuf = np.zeros((2, nc, dim), npf)
        self._static_done = False
        self.set_time(0.0, 0.0)

    def set_time(self, t: float, dt: float) -> None:
        """The CPIC colliders' poses at the start and the end of the substep [t, t + dt] (host; only when
        one moves, else once)."""
        if self._static_done and not self.any_moving:
            return
        d = self.dim
        for j, m in enumerate(self.motions):
            for slot, ts in enumerate((t, t + dt)):
                R, c, p, v, w = np.eye(d), np.zeros(d), np.zeros(d), np.zeros(d), np.zeros(3)
                if m is not None:
                    ps = m.pose(ts)
                    R, c, p, v, w = ps.R, ps.c, np.asarray(m.pivot[:d]), ps.v, ps.w
                self._buf[slot, j, : d * d] = np.asarray(R).reshape(-1)
                self._buf[slot, j, 9 : 9 + d] = c
                self._buf[slot, j, 12 : 12 + d] = p
                self._buf[slot, j, 15:18] = w
                self._vbuf[slot, j] = v
        self.pose.from_numpy(self._buf)
        self.vel.from_numpy(self._vbuf)
        self._static_done = True

    def bind(self, grid, bbox, T: int, gravity, gh: int) -> None:
        """The P2G grid copies (their channels gh .. gh + dim: the ghost momentum and mass, what particles
        sent to the nodes across a CPIC collider), their node boxes and the gravity field."""
        self.grid, self.bbox, self.T, self.gravity, self.gh = grid, bbox, int(T), gravity, int(gh)
        self.grid_shape = tuple(int(s) for s in grid.shape[1:])

    # ------------------------------------------------------------------ kernel side

    @ti.func
    def ghost(self, c, q, w, m):
        """Grid channel value c with the ghost momentum w q and mass w m added (an incompatible node)."""
        for d in ti.static(range(self.dim)):
            c[self.gh + d] = w * q[d]
        c[self.gh + self.dim] = w * m
        return c

    @ti.func
    def _ghost_raw(self, J):
        g = ti.Vector.zero(self.f, self.dim + 1)
        for t in range(self.T):
            a = self.bbox[t, 0]
            b = self.bbox[t, 1]
            inside = True
            for d in ti.static(range(self.dim)):
                inside = inside and a[d] <= J[d] and J[d] < b[d]
            if inside:
                gt = self.grid[t, J]
                for c in ti.static(range(self.dim + 1)):
                    g[c] += gt[self.gh + c]
        return g

    @ti.func
    def node_velocity(self, J, xp, vg, jj, dt):
        """Velocity a node J across CPIC collider jj gives a particle at xp: the ghost node's (the momentum
        and mass the particles of this side sent it, gravity, then the collider's contact condition with
        the normal towards this side: the node as inside a thick wall); vg where it holds no mass."""
        g = self._ghost_raw(J)
        v = vg
        m = g[self.dim]
        if m > 0:
            for d in ti.static(range(self.dim)):
                v[d] = g[d] / m
            v += dt * self.gravity[None]
            yp = self.to_body(0, jj, xp)
            n = self._R(0, jj) @ (self._normal_body(jj) * ti.cast(self._side(jj, yp), self.f))
            xJ = ti.Vector(self.origin, dt=self.f) + J.cast(self.f) * self.dx
            vw = self.surface_velocity(0, jj, xJ)
            vr = v - vw
            vn = vr.dot(n)
            ck = self.contact[jj]
            mu = self.mu[jj]
            if ck == 1:
                vr = vr * 0.0
            elif (ck == 0 and (vn < 0 or mu <= 0)) or (ck == 2 and vn < 0):
                vt = vr - vn * n
                if vn < 0 and mu > 0:
                    vt_norm = vt.norm()
                    if vt_norm > 0:
                        vt *= ti.max(0.0, 1.0 + mu * vn / vt_norm)
                vr = vt
            v = vr + vw
        return v

    @ti.func
    def ghost_sum(self, base, fx, mask, xp, vg, jj, dt):
        """(s, b) over the incompatible stencil nodes o: s = sum w_o v_o and b[d] = sum w_o v_o o[d], v_o
        their ``node_velocity`` (G2P's velocity and the columns of its gradient sum). One run-time loop:
        the node's velocity is inlined once, not once per stencil node."""
        dim = ti.static(self.dim)
        s = ti.Vector.zero(self.f, dim)
        b = ti.Matrix.zero(self.f, dim, dim)  # column d: sum w v o[d]
        for o in range(3**dim):
            if (mask >> o) & 1 == 1:
                off = ti.Vector.zero(ti.i32, dim)
                r = o
                for e in ti.static(range(dim)):
                    off[dim - 1 - e] = r % 3
                    r = r // 3
                w = ti.cast(1.0, self.f)
                for e in ti.static(range(dim)):
                    au = ti.abs(fx[e] - off[e])
                    we = 0.0
                    if au < 0.5:
                        we = 0.75 - au * au
                    elif au < 1.5:
                        we = 0.5 * (1.5 - au) ** 2
                    w *= we
                wv = w * self.node_velocity(base + off, xp, vg, jj, dt)
                s += wv
                for e in ti.static(range(dim)):
                    for d in ti.static(range(dim)):
                        b[d, e] += wv[d] * off[e]
        return s, b

    @ti.func
    def _R(self, slot, j):
        d = ti.static(self.dim)
        R = ti.Matrix.zero(self.f, d, d)
        for a in ti.static(range(d)):
            for b in ti.static(range(d)):
                R[a, b] = self.pose[slot, j, a * d + b]
        return R

    @ti.func
    def _vec(self, slot, j, off: ti.template()):
        d = ti.static(self.dim)
        v = ti.Vector.zero(self.f, d)
        for a in ti.static(range(d)):
            v[a] = self.pose[slot, j, off + a]
        return v

    @ti.func
    def to_body(self, slot, j, x):
        """R^T (x - c) + p, relative to the collider's centre (Box) or point (Plane)."""
        return (
            self._R(slot, j).transpose() @ (x - self._vec(slot, j, 9))
            + self._vec(slot, j, 12)
            - self.centre[j]
        )

    @ti.func
    def from_body(self, slot, j, y):
        return self._R(slot, j) @ (y + self.centre[j] - self._vec(slot, j, 12)) + self._vec(slot, j, 9)

    @ti.func
    def surface_velocity(self, slot, j, x):
        r = x - self._vec(slot, j, 9)
        out = self.vel[slot, j]
        if ti.static(self.dim == 2):
            wz = self.pose[slot, j, 17]
            out += ti.Vector([-wz * r[1], wz * r[0]])
        else:
            w = ti.Vector([self.pose[slot, j, 15], self.pose[slot, j, 16], self.pose[slot, j, 17]])
            out += w.cross(r)
        return out

    @ti.func
    def _comp(self, y, a):
        """y[a] for a run-time axis a (static loop: no dynamic indexing of a local vector)."""
        r = ti.cast(0.0, self.f)
        for e in ti.static(range(self.dim)):
            if e == a:
                r = y[e]
        return r

    @ti.func
    def _side(self, j, y):
        """The side (+1 / -1) of body-frame point y: along the thin axis (Box), the normal (Plane)."""
        s = 0.0
        if self.kind[j] == 0:
            s = y.dot(self.half[j])
        else:
            s = self._comp(y, self.thin[j])
        r = 1
        if s < 0:
            r = -1
        return r

    @ti.func
    def _normal_body(self, j):
        n = ti.Vector.zero(self.f, self.dim)
        if self.kind[j] == 0:
            n = self.half[j]
        else:
            for e in ti.static(range(self.dim)):
                if e == self.thin[j]:
                    n[e] = 1.0
        return n

    @ti.func
    def _crosses(self, j, yp, yi):
        """Does the body-frame segment yp -> yi cross collider j's mid-surface (within its extent)?"""
        sp = self._side(j, yp)
        si = self._side(j, yi)
        hit = False
        if sp != si:
            hit = True
            if self.kind[j] == 1:
                a = self.thin[j]
                pa = self._comp(yp, a)
                den = pa - self._comp(yi, a)
                t = 0.0
                if den != 0:
                    t = pa / den
                q = yp + t * (yi - yp)
                for e in ti.static(range(self.dim)):
                    if e != a and ti.abs(q[e]) > self.half[j][e]:
                        hit = False
        return hit

    @ti.func
    def _near(self, j, yp):
        """Can the 3^dim stencil of a particle at body-frame yp reach across collider j?"""
        reach = 2.0 * self.dx
        near = True
        if self.kind[j] == 0:
            near = ti.abs(yp.dot(self.half[j])) < reach
        else:
            for e in ti.static(range(self.dim)):
                if ti.abs(yp[e]) > self.half[j][e] + reach:
                    near = False
        return near

    @ti.func
    def classify(self, xp, fx, vp):
        """For a particle at xp (stencil position fx in cells, velocity vp): (mask, W, M1, vg, j) with bit
        o of mask set for each incompatible stencil node o (o = i 3 + j in 2D, i 9 + j 3 + k in 3D),
        W = sum_excl w_o, M1 = sum_excl w_o (o - fx) [cells], vg the ghost velocity and j the CPIC
        collider (-1 when all nodes are compatible)."""
        dim = ti.static(self.dim)
        mask = 0
        W = ti.cast(0.0, self.f)
        M1 = ti.Vector.zero(self.f, dim)
        vg = vp
        jj = -1
        for j in range(self.n):
            yp = self.to_body(0, j, xp)
            if self._near(j, yp):
                Rt = self._R(0, j).transpose()
                for o in range(3**dim):
                    off = ti.Vector.zero(self.f, dim)
                    r = o
                    for e in ti.static(range(dim)):
                        off[dim - 1 - e] = r % 3
                        r = r // 3
                    rel = (off - fx) * self.dx
                    yi = yp + Rt @ rel
                    if (mask >> o) & 1 == 0 and self._crosses(j, yp, yi):
                        mask |= 1 << o
                        w = ti.cast(1.0, self.f)
                        for e in ti.static(range(dim)):
                            u = fx[e] - off[e]  # distance in cells from node to particle
                            au = ti.abs(u)
                            we = 0.0
                            if au < 0.5:
                                we = 0.75 - au * au
                            elif au < 1.5:
                                we = 0.5 * (1.5 - au) ** 2
                            w *= we
                        W += w
                        M1 += w * (off - fx)
                        if jj < 0:
                            jj = j
        if jj >= 0:
            # the ghost velocity: the particle's own, less its approach to the collider
            yp = self.to_body(0, jj, xp)
            n = self._R(0, jj) @ (self._normal_body(jj) * ti.cast(self._side(jj, yp), self.f))
            vr = self.surface_velocity(0, jj, xp)
            vn = (vp - vr).dot(n)
            if vn < 0:
                vg = vp - vn * n
        return mask, W, M1, vg, jj

    @ti.func
    def keep(self, mask, o: ti.template()):
        """1 for a compatible stencil node o, 0 for an incompatible one."""
        r = ti.cast(1.0, self.f)
        if (mask >> o) & 1 == 1:
            r = 0.0
        return r

    @ti.func
    def add_load(self, j, x, J):
        """Collider j (a CPIC index) took the impulse J [N s] at x (only if named; moment about its moving
        pivot at the start of the substep)."""
        if ti.static(self.any_named) and self.named[j] != 0:
            k = self.k[j]
            c = self._vec(0, j, 9)
            r = x - c
            M = ti.Vector.zero(self.f, 3)
            if ti.static(self.dim == 2):
                M[2] = r[0] * J[1] - r[1] * J[0]
            else:
                M = r.cross(J)
            for i in ti.static(range(self.dim)):
                ti.atomic_add(self.boundary.poses.load[k, i], ti.cast(J[i], ti.f64))
            for i in ti.static(range(3)):
                ti.atomic_add(self.boundary.poses.load[k, self.dim + i], ti.cast(M[i], ti.f64))

    @ti.func
    def keep_side(self, x_old, x_new, v, mp):
        """A particle that ended inside a thin CPIC Box, or whose path x_old (start of the substep) -> x_new
        (its end) crossed it, goes onto the broad face on the side it started from, its velocity into the
        plate (relative to it) removed: the plate's edge splits the material instead of pushing it ahead
        (boundary.GridBoundary.project_particle leaves CPIC Boxes to this). Returns (x, v); a named
        collider takes the momentum removed (mass ``mp``)."""
        for j in range(self.n):
            if self.kind[j] == 1:
                y0 = self.to_body(0, j, x_old)
                if self._near(j, y0):
                    y1 = self.to_body(1, j, x_new)
                    h = self.half[j]
                    inside = True
                    for e in ti.static(range(self.dim)):
                        inside = inside and ti.abs(y1[e]) < h[e]
                    if inside or self._crosses(j, y0, y1):
                        a = self.thin[j]
                        s = ti.cast(self._side(j, y0), self.f)
                        for e in ti.static(range(self.dim)):
                            if e == a:
                                y1[e] = s * (h[e] + 1e-4 * self.dx)
                        x_new = self.from_body(1, j, y1)
                        n = self._R(1, j) @ (self._normal_body(j) * s)
                        vr = self.surface_velocity(1, j, x_new)
                        vn = (v - vr).dot(n)
                        if vn < 0:
                            v = v - vn * n
                            self.add_load(j, x_new, mp * vn * n)
        return x_new, v
