"""Particle-particle contact for PBD: a hashed cell grid rebuilt by a counting sort every substep, and a
Jacobi contact pass with static and kinetic Coulomb friction (Macklin, Mueller, Chentanez and Kim 2014,
"Unified particle physics for real-time applications", sec. 6.1, eqs. 23-24).

The grid (hashgrid.py) has cells of twice the contact distance (the largest 2 x radius), so the 2 x 2 x 2
cells nearest a vertex hold every vertex within reach. Each vertex computes its own
correction from all its neighbours (no atomics, order independent) and the corrections are applied
together: Jacobi, like Genesis's, which is enough for contact (one pair, one push).

Two vertices of the same meshed body (cloth, rod, soft body) are not pushed apart when they were
closer than the contact distance in the rest shape (mesh neighbours): what a sheet's own edges hold
together is not a collision. Free particles get a body id of their own each (``body`` < 0).
"""

from __future__ import annotations

from simcli.backend import stdout_to_stderr
from simcli.solvers.pbd.hashgrid import HashGrid

with stdout_to_stderr():
    import taichi as ti


class ParticleContact:
    """Fields and kernels of the hashed grid and the contact pass, for ``n`` vertices."""

    def __init__(self, n: int, f, cell: float, x, xp, x0, w, rad, body, mu_s, mu_k, count=None):
        """``count``: a func giving the active count (emitters, sinks; ``n`` is then the capacity)."""
        self.n, self.cell = n, float(cell)
        self.grid = grid = HashGrid(x, 0, n, self.cell, count)
        D = x.n  # 3, or 2 in a 2D scene
        self.dpos = dpos = ti.Vector.field(D, f, shape=n)
        start, srt = grid.start, grid.sorted
        inv_cell = 1.0 / self.cell
        if D == 3:
            near = [(t // 4, (t // 2) % 2, t % 2) for t in range(8)]
        else:
            near = [(t // 2, t % 2) for t in range(4)]
        around = grid.slots_around(near)
        active = count is not None

        @ti.func
        def npoints():
            out = n
            if ti.static(active):
                out = count()
            return out

        @ti.kernel
        def build():
            grid.build()

        @ti.kernel
        def collide():
            for i in range(npoints()):
                dp = ti.Vector.zero(float, D)
                if w[i] > 0:
                    sl = around(ti.floor(x[i] * inv_cell - 0.5, ti.i32))  # the 2 x 2 (x 2) cells within reach
                    for t in ti.static(range(len(near))):
                        s = sl[t]
                        for q in range(start[ti.max(s, 0)], start[s + 1]):  # empty for s = -1
                            j = srt[q]
                            if j != i and not (body[i] == body[j] and body[i] >= 1 << 20):  # liquid pairs
                                d = x[i] - x[j]
                                dist = d.norm()
                                target = rad[i] + rad[j]
                                near_at_rest = (
                                    body[i] == body[j] and (x0[i] - x0[j]).norm() <= target * 1.0001
                                )
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
            for i in range(npoints()):
                x[i] += dpos[i]

        self.build, self.collide = build, collide

    def step(self) -> None:
        self.build()
        self.collide()
