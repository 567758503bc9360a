"""The hashed cell grid of PBD's particle passes (contact, position-based fluids): cells of a given size
hashed into a table of 2^k slots (at least the point count), so its memory does not depend on the domain
size, rebuilt by a counting sort every substep. A slot shared by two cells only adds candidates that the
caller's distance test rejects; ``slots_around`` lists each slot once, so no candidate is visited twice.
"""

from __future__ import annotations

import numpy as np

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti


def table_size(n: int) -> int:
    return 1 << max(10, int(np.ceil(np.log2(max(n, 2)))))


class HashGrid:
    """Cells of size ``cell`` over the points x[lo], ..., x[lo + n - 1].

    ``build()`` (top-level loops: call it at kernel scope) sorts the points by slot: ``sorted`` holds their
    local indices (0 .. n - 1), those of slot s at ``start[s]`` .. ``start[s + 1] - 1``. ``cell_of(p)`` is the
    cell of a position, ``slots_around(offsets)`` a func giving the slots of the cells c0 + offsets[t]
    (-1 for a slot already listed).

    With ``count`` (a func: the number of points now, emitters and sinks), ``n`` is the capacity: the points
    are x[lo], ..., x[lo + count() - 1] and the table uses its first ``table_size(count())`` slots only
    (``resize`` sets it, from the host, when the count changes), so neither the points nor the slots beyond
    the count cost anything per build."""

    def __init__(self, x, lo: int, n: int, cell: float, count=None) -> None:
        n_now = count
        self.slots = slots = table_size(n)
        self.count = count = ti.field(ti.i32, shape=slots)
        self.start = start = ti.field(ti.i32, shape=slots + 1)
        self.cursor = cursor = ti.field(ti.i32, shape=slots)
        self.sorted = srt = ti.field(ti.i32, shape=n)
        inv_cell = 1.0 / float(cell)
        dim = x.n  # the points' components: 3, or 2 in a 2D scene
        active = n_now is not None
        self.mask = mask = ti.field(ti.i32, shape=()) if active else None
        if active:
            mask[None] = slots - 1

        @ti.func
        def npoints():
            out = n
            if ti.static(active):
                out = n_now()
            return out

        @ti.func
        def nslots():
            out = slots
            if ti.static(active):
                out = mask[None] + 1
            return out

        @ti.func
        def slot_of(c):
            hsh = (c[0] * 73856093) ^ (c[1] * 19349663)
            if ti.static(dim == 3):
                hsh = (c[0] * 73856093) ^ (c[1] * 19349663) ^ (c[2] * 83492791)
            out = hsh & (slots - 1)
            if ti.static(active):
                out = hsh & mask[None]
            return out

        @ti.func
        def cell_of(p):
            return ti.floor(p * inv_cell, ti.i32)

        @ti.func
        def build():
            for s in range(nslots()):
                count[s] = 0
            for a in range(npoints()):
                ti.atomic_add(count[slot_of(cell_of(x[lo + a]))], 1)
            ti.loop_config(serialize=True)
            for s in range(nslots()):
                start[s + 1] = start[s] + count[s]
            for s in range(nslots()):
                cursor[s] = start[s]
            for a in range(npoints()):
                k = ti.atomic_add(cursor[slot_of(cell_of(x[lo + a]))], 1)
                srt[k] = a

        self.slot_of, self.cell_of, self.build = slot_of, cell_of, build

    def resize(self, n_now: int) -> None:
        """Use the first table_size(n_now) slots (active mode; host side, when the count changed)."""
        if self.mask is not None:
            self.mask[None] = min(self.slots, table_size(n_now)) - 1

    def slots_around(self, offsets: list[tuple[int, ...]]):
        """A func c0 -> the slots of the cells c0 + offsets[t], in order, with -1 where a slot was listed
        before (two of the cells hashed to one slot: visit it once)."""
        k = len(offsets)
        offs = [list(o) for o in offsets]
        slot_of = self.slot_of

        @ti.func
        def around(c0):
            sl = ti.Vector([-1] * k)
            for t in ti.static(range(k)):
                s = slot_of(c0 + ti.Vector(offs[t]))
                for u in ti.static(range(t)):
                    if sl[u] == s:
                        s = -1
                sl[t] = s
            return sl

        return around
