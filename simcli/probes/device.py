"""The probes' device path: a sample reads only the particles near its probes.

The host path (``Solver.entity_arrays``) copies every field a probe reads, over all particles, to the host at
each sample, and culls them there: at 146,520 MPM particles with 6 probes sampled every step that was 17% of
the stepping time (docs/PERFORMANCE.md, "Probes"). Here, per family (:class:`ProbeView`), one kernel over
the live particles tests each against every window of the family's probes (a point probe's box of half-width
its reach, a height gauge's column; a little larger than the host's own tests, rounded outwards in the
positions' precision) and appends the row of each one inside (window, output order key, position, the fields
read) to a short table, which one copy brings to the host; MPM's derived J, pressure, ... are computed for
the listed particles alone by a second kernel, with the frame outputs' per-particle code. Two or three
launches a sample: on a loaded machine each launch waits for its threads, so their number, more than the
work, sets a sample's cost.

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

    CAP0 = 256  # rows at first; grown to fit when a sample finds more particles in the windows

    def __init__(self, view, dim: int, windows: list[tuple[str, np.ndarray, np.ndarray]], fields: list[str]):
        """``windows``: (entity name, lower corner, upper corner) boxes; ``fields``: the output fields read
        besides position."""
        self.view, self.dim = view, dim
        self.entities = [w[0] for w in windows]
        self.fields = [f for f in fields if f != "position"]
        nw = len(windows)
        self.nw = nw
        # every field declared before any is written (one Taichi SNode tree, not one per field)
        self.src = [view.field(f) for f in self.fields]
        self.ncomp = [_ncomp(s) for s in self.src]
        self.ncols = 2 + dim + sum(self.ncomp)
        self.cols = list(2 + dim + np.cumsum([0] + self.ncomp[:-1]).astype(int)) if self.ncomp else []
        self.derived = [f for f in self.fields if f in view.derived]
        f = ti.f64 if np.dtype(view.dtype) == np.float64 else ti.f32
        self.lo = ti.Vector.field(dim, f, shape=nw + 1)
        self.hi = ti.Vector.field(dim, f, shape=nw + 1)
        self.total = ti.field(ti.i32, shape=())
        self._alloc(self.CAP0)
        # the boxes in the positions' precision, rounded outwards; and the box around them all, which most
        # particles fail at once
        lo = np.array([w[1] for w in windows], dtype=np.float64).reshape(nw, dim)
        hi = np.array([w[2] for w in windows], dtype=np.float64).reshape(nw, dim)
        lo = np.nextafter(lo.astype(view.dtype), -np.inf)
        hi = np.nextafter(hi.astype(view.dtype), np.inf)
        self.lo.from_numpy(np.vstack([lo, lo.min(axis=0)]))
        self.hi.from_numpy(np.vstack([hi, hi.max(axis=0)]))

    def _alloc(self, cap: int) -> None:
        self.cap = cap
        self.out = ti.field(ti.f64, shape=(cap + 1, self.ncols))  # the rows, then the count (out[cap, 0])
        self.sel = ti.field(ti.i32, shape=cap) if self.derived else None  # each row's slot (MPM's derive)
        self._sample = self._make_sample()
        self._derive = self._make_derive() if self.derived else None

    def _make_sample(self):
        """One kernel: every live particle inside a window appends its row (window, key, position, the fields
        that are not derived; with derived fields its slot to ``sel``) to ``out``; the count goes to
        out[cap, 0]."""
        x, key, lo, hi, total, out, sel = (
            self.view.x,
            self.view.key,
            self.lo,
            self.hi,
            self.total,
            self.out,
            self.sel,
        )
        dim, nw, cap = self.dim, self.nw, self.cap
        derived = set(self.derived)
        plain = [(j, s) for j, (f, s) in enumerate(zip(self.fields, self.src)) if f not in derived]
        src, ncomp, cols = tuple(s for _, s in plain), tuple(self.ncomp[j] for j, _ in plain), []
        for j, _ in plain:
            cols.append(self.cols[j])
        has_key = key is not None
        has_sel = sel is not None

        @ti.kernel
        def sample(n: ti.i32):
            total[None] = 0
            for p in range(n):
                xp = x[p]
                if (xp >= lo[nw]).all() and (xp <= hi[nw]).all():
                    for w in range(nw):
                        if (xp >= lo[w]).all() and (xp <= hi[w]).all():
                            k = ti.atomic_add(total[None], 1)
                            if k < cap:
                                if ti.static(has_sel):
                                    sel[k] = p
                                out[k, 0] = ti.cast(w, ti.f64)
                                if ti.static(has_key):
                                    out[k, 1] = ti.cast(key[p], ti.f64)
                                else:
                                    out[k, 1] = ti.cast(p, ti.f64)
                                for d in ti.static(range(dim)):
                                    out[k, 2 + d] = ti.cast(xp[d], ti.f64)
                                for j in ti.static(range(len(src))):
                                    if ti.static(ncomp[j] == 1):
                                        out[k, cols[j]] = ti.cast(src[j][p], ti.f64)
                                    else:
                                        for c in ti.static(range(ncomp[j])):
                                            out[k, cols[j] + c] = ti.cast(src[j][p][c], ti.f64)
            out[cap, 0] = ti.cast(total[None], ti.f64)

        return sample

    def _make_derive(self):
        """MPM: the derived fields at the listed slots (the frame outputs' per-particle code; the same values
        bit for bit, tests/unit/test_probes_device.py), copied into their columns."""
        derive, total, out, sel, cap = self.view.derive, self.total, self.out, self.sel, self.cap
        derived = set(self.derived)
        dj = [j for j, f in enumerate(self.fields) if f in derived]
        src, cols = tuple(self.src[j] for j in dj), tuple(self.cols[j] for j in dj)

        @ti.kernel
        def run():
            for k in range(ti.min(total[None], cap)):
                p = sel[k]
                derive(p)
                for j in ti.static(range(len(src))):
                    out[k, cols[j]] = ti.cast(src[j][p], ti.f64)

        return run

    def read(self) -> list[dict[str, np.ndarray]]:
        """Per window: the arrays (position and the fields) of its entity's particles within it, in output
        order."""
        n = int(self.view.n_live())
        self._sample(n)
        if self._derive is not None:
            self._derive()
        table = self.out.to_numpy()
        m = int(table[self.cap, 0])
        if m > self.cap:  # more particles in the windows than rows: grow and sample again
            self._alloc(1 << int(m * 1.25).bit_length())
            self._sample(n)
            if self._derive is not None:
                self._derive()
            table = self.out.to_numpy()
            m = int(table[self.cap, 0])
        table = table[:m]
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
