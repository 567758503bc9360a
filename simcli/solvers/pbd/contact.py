"""Particle-particle contact for PBD: a hashed cell grid rebuilt by a counting sort every substep, and a
Jacobi contact pass with static and kinetic Coulomb friction (Macklin, Mueller, Chentanez and Kim 2014,
"Unified particle physics for real-time applications", sec. 6.1, eqs. 23-24).

The grid has cells of twice the contact distance (the largest 2 x radius), so the 2 x 2 x 2 cells
nearest a vertex hold every vertex within reach, hashed into a table of 2^k slots (at least the vertex
count), so its memory does not depend on the domain size; a slot shared by
two cells only adds candidates that the distance test rejects. Each vertex computes its own
correction from all its neighbours (no atomics, order independent) and the corrections are applied
together: Jacobi, like Genesis's, which is enough for contact (one pair, one push).

Two vertices of the same meshed body (cloth, rod, soft body) are not pushed apart when they were
closer than the contact distance in the rest shape (mesh neighbours): what a sheet's own edges hold
together is not a collision. Free particles get a body id of their own each (``body`` < 0).
"""

from __future__ import annotations

import numpy as np

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti


def table_size(n: int) -> int:
    return 1 << max(10, int(np.ceil(np.log2(max(n, 2)))))


class ParticleContact:
    """Fields and kernels of the hashed grid and the contact pass, for ``n`` vertices."""

    def __init__(self, n: int, f, cell: float, x, xp, x0, w, rad, body, mu_s, mu_k):
        self.n, self.cell = n, float(cell)
        self.slots = table_size(n)
        self.count = ti.field(ti.i32, shape=self.slots)
        self.start = ti.field(ti.i32, shape=self.slots + 1)
        self.cursor = ti.field(ti.i32, shape=self.slots)
        self.sorted = ti.field(ti.i32, shape=n)
        self.dpos = ti.Vector.field(3, f, shape=n)
        slots, count, start, cursor, srt, dpos = self.slots, self.count, self.start, self.cursor, self.sorted, \
            self.dpos
        inv_cell = 1.0 / self.cell

        @ti.func
        def slot_of(c):
            h = (c[0] * 73856093) ^ (c[1] * 19349663) ^ (c[2] * 83492791)
            return h & (slots - 1)

        @ti.func
        def cell_of(p):
            return ti.floor(p * inv_cell, ti.i32)

        @ti.kernel
        def build():
            for s in range(slots):
                count[s] = 0
            for i in range(n):
                ti.atomic_add(count[slot_of(cell_of(x[i]))], 1)
            ti.loop_config(serialize=True)
            for s in range(slots):
                start[s + 1] = start[s] + count[s]
            for s in range(slots):
                cursor[s] = start[s]
            for i in range(n):
                k = ti.atomic_add(cursor[slot_of(cell_of(x[i]))], 1)
                srt[k] = i

        @ti.kernel
        def collide():
            for i in range(n):
                dp = ti.Vector.zero(float, 3)
                if w[i] > 0:
                    ci = ti.floor(x[i] * inv_cell - 0.5, ti.i32)  # the 2 x 2 x 2 cells within reach
                    seen = ti.Vector([-1] * 8)
                    for t in ti.static(range(8)):
                        s = slot_of(ci + ti.Vector([t // 4, (t // 2) % 2, t % 2]))
                        dup = False  # two of the 8 cells hashed to one slot: visit it once
                        for u in ti.static(range(t)):
                            if seen[u] == s:
                                dup = True
                        seen[t] = s
                        for q in range(start[s], start[s + 1] if not dup else start[s]):
                            j = srt[q]
                            if j != i and not (body[i] == body[j] and body[i] >= 1 << 20):  # liquid pairs
                                d = x[i] - x[j]
                                dist = d.norm()
                                target = rad[i] + rad[j]
                                near_at_rest = body[i] == body[j] and (x0[i] - x0[j]).norm() <= target * 1.0001
                                if dist < target and dist > 1e-12 and not near_at_rest:
                                    nrm = d / dist
                                    share = w[i] / (w[i] + w[j])
                                    pen = target - dist
                                    dp += share * pen * nrm
                                    # friction on the relative tangential displacement over the substep
                                    rel = (x[i] - xp[i]) - (x[j] - xp[j])
                                    tang = -(rel - nrm * nrm.dot(rel))
                                    lt = tang.norm()
                                    ms = ti.max(mu_s[i], mu_s[j])
                                    mk = ti.max(mu_k[i], mu_k[j])
                                    if lt < ms * pen:
                                        dp += share * tang
                                    elif lt > 0:
                                        dp += share * tang * ti.min(1.0, mk * pen / lt)
                dpos[i] = dp
            for i in range(n):
                x[i] += dpos[i]

        self.build, self.collide = build, collide
        self.start.fill(0)

    def step(self) -> None:
        self.build()
        self.collide()
