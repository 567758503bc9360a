"""The probes' device path: a sample reads only the particles near its probes.

The host path (``Solver.entity_arrays``) copies every field a probe reads, over all particles, to the host at
each sample, and culls them there: at 146,520 MPM particles with 6 probes sampled every step that was 17% of
the stepping time (docs/PERFORMANCE.md, "Probes"). Here, per family (:class:`ProbeView`):

1. ``select``: one kernel over the live particles tests each against every window of the family's probes
   (a point probe's box of half-width its reach, a height gauge's column), a little larger than the host's
   own test, and appends (window, slot) of those inside to a short list;
2. ``derive`` (MPM's J, pressure, ...): computes the derived fields only at the listed slots;
3. ``gather``: copies each listed particle's output order key, position and the fields read into one small
   float64 table, read back in one copy.

The host then keeps, per window, the rows of the window's entity, sorted by key: the rows ``entity_arrays``
would give, restricted to a superset of the particles the sampling functions (sampling.py) keep, in the same
order and with the same dtypes, so the values are the same bit for bit.
"""

# (no "from __future__ import annotations": Taichi reads the kernels' annotations as types)

import numpy as np

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti

BIG = 1.0e30  # a window's extent along a height gauge's axis
MARGIN = 1.0e-5  # relative: the windows are this much larger than the host's tests (f32 positions)


def _ncomp(fld) -> int:
    n = getattr(fld, "n", None)  # vector fields
    return 1 if n is None else int(n)


class FamilySampler:
    """The windows of one family's probes and the kernels that read them."""

    def __init__(self, view, dim: int, windows: list[tuple[str, np.ndarray, np.ndarray]], fields: list[str]):
        """``windows``: (entity name, lower corner, upper corner) boxes; ``fields``: the output fields read
        besides position."""
        self.view, self.dim = view, dim
        self.entities = [w[0] for w in windows]
        self.fields = [f for f in fields if f != "position"]
        nw = len(windows)
        self.nw = nw
        # the boxes in the positions' precision, rounded outwards; and the box around them all, which most
        # particles fail at once
        f = ti.f64 if np.dtype(view.dtype) == np.float64 else ti.f32
        lo = np.array([w[1] for w in windows], dtype=np.float64).reshape(nw, dim)
        hi = np.array([w[2] for w in windows], dtype=np.float64).reshape(nw, dim)
        lo = np.nextafter(lo.astype(view.dtype), -np.inf)
        hi = np.nextafter(hi.astype(view.dtype), np.inf)
        self.lo = ti.Vector.field(dim, f, shape=nw + 1)
        self.hi = ti.Vector.field(dim, f, shape=nw + 1)
        self.lo.from_numpy(np.vstack([lo, lo.min(axis=0)]))
        self.hi.from_numpy(np.vstack([hi, hi.max(axis=0)]))
        self.total = ti.field(ti.i32, shape=())
        self.src = [view.field(f) for f in self.fields]
        self.ncomp = [_ncomp(s) for s in self.src]
        self.ncols = 2 + dim + sum(self.ncomp)
        self.derived = [f for f in self.fields if f in view.derived]
        self._alloc(256)

    def _alloc(self, cap: int) -> None:
        self.cap = cap
        self.sel = ti.field(ti.i32, shape=cap)
        self.selw = ti.field(ti.i32, shape=cap)
        self.out = ti.field(ti.f64, shape=(cap, self.ncols))
        self._select = self._make_select()
        self._gather = self._make_gather()
        self._derive = self.view.derive(self.sel) if self.derived else None

    def _make_select(self):
        x, lo, hi, total, sel, selw = self.view.x, self.lo, self.hi, self.total, self.sel, self.selw
        nw, cap = self.nw, self.cap

        @ti.kernel
        def select(n: ti.i32):
            total[None] = 0
            for p in range(n):
                xp = x[p]
                if (xp >= lo[nw]).all() and (xp <= hi[nw]).all():
                    for w in range(nw):
                        if (xp >= lo[w]).all() and (xp <= hi[w]).all():
                            k = ti.atomic_add(total[None], 1)
                            if k < cap:
                                sel[k] = p
                                selw[k] = w

        return select

    def _make_gather(self):
        x, key, sel, selw, out = self.view.x, self.view.key, self.sel, self.selw, self.out
        dim, src, ncomp = self.dim, tuple(self.src), tuple(self.ncomp)
        has_key = key is not None
        cols = []
        c = 2 + dim
        for n in ncomp:
            cols.append(c)
            c += n

        @ti.kernel
        def gather(m: ti.i32):
            for k in range(m):
                p = sel[k]
                out[k, 0] = ti.cast(selw[k], ti.f64)
                if ti.static(has_key):
                    out[k, 1] = ti.cast(key[p], ti.f64)
                else:
                    out[k, 1] = ti.cast(p, ti.f64)
                for d in ti.static(range(dim)):
                    out[k, 2 + d] = ti.cast(x[p][d], ti.f64)
                for j in ti.static(range(len(src))):
                    if ti.static(ncomp[j] == 1):
                        out[k, cols[j]] = ti.cast(src[j][p], ti.f64)
                    else:
                        for c in ti.static(range(ncomp[j])):
                            out[k, cols[j] + c] = ti.cast(src[j][p][c], ti.f64)

        return gather

    def read(self) -> list[dict[str, np.ndarray]]:
        """Per window: the arrays (position and the fields) of its entity's particles within it, in output
        order."""
        n = int(self.view.n_live())
        self._select(n)
        m = int(self.total[None])
        if m > self.cap:  # more particles in the windows than rows: grow and select again
            self._alloc(1 << int(m * 1.25).bit_length())
            self._select(n)
            m = int(self.total[None])
        if m and self._derive is not None:
            self._derive(m)
        if m:
            self._gather(m)
            table = self.out.to_numpy()[:m]
        else:
            table = np.zeros((0, self.ncols))
        dt = self.view.dtype
        # rows by window, then by key (output order): the windows' row ranges from one sort
        order = np.lexsort((table[:, 1], table[:, 0]))
        table = table[order]
        bounds = np.searchsorted(table[:, 0], np.arange(self.nw + 1) - 0.5)
        res = []
        for w, name in enumerate(self.entities):
            lo, hi = self.view.ranges[name]
            t = table[bounds[w] : bounds[w + 1]]
            t = t[(t[:, 1] >= lo) & (t[:, 1] < hi)]
            a = {"position": t[:, 2 : 2 + self.dim].astype(dt)}
            c = 2 + self.dim
            for f, nc in zip(self.fields, self.ncomp):
                a[f] = (t[:, c] if nc == 1 else t[:, c : c + nc]).astype(dt)
                c += nc
            res.append(a)
        return res
