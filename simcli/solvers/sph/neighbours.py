"""Neighbour search that scales linearly: a uniform cell grid over the domain (plus a band for the
boundary particles), rebuilt every substep by a counting sort that also reorders the particles.

* **Cells.** Cell size = support radius / ``CELLS_PER_SUPPORT`` (2), so a particle's neighbours lie in
  the (2 x 2 + 1)^dim cells around its own. The grid covers the whole domain: one slot per cell, no
  hash, so cells never alias (Genesis hashes into at most 150^3 buckets; beyond that, distant cells
  share a bucket and every lookup scans both).
* **Counting sort** (each substep): count particles per cell, exclusive prefix sum over the cells
  (blocked: parallel per block, serial over the block sums), scatter. On the CPU the counting pass is
  serial, which makes the rank of a particle within its cell, hence the order and every sum,
  deterministic: a run is bitwise reproducible and restarts bit-for-bit. On GPUs it uses atomics.
* **Reordering.** The scatter moves every particle's state to its cell-sorted slot, so particles of a
  cell are contiguous and the cells of one grid row are contiguous too: a neighbour query scans
  5 (2D) or 25 (3D) contiguous index ranges, and neighbours sit close in memory. Sorting costs one
  copy of the state per substep (a few percent of a WCSPH substep); a solver with many neighbour
  passes per substep (DFSPH) gains most from it. ``pid`` keeps each particle's original index for output.
* **Neighbour lists.** The first pass of a substep stores, per particle, up to ``capacity`` neighbour
  indices and (DFSPH) the kernel gradient's factor s_ij, grad W_ij = (x_i - x_j) s_ij (4 bytes, not the
  vector's 12: the iterations rebuild the vector from the positions, which a substep's solves do not
  move); every later pass of the substep (viscosity, pressure, DFSPH iterations) walks that list instead
  of the cells. A particle with more neighbours than the
  capacity (a compression far beyond any liquid's) drops the excess; the count is reported.
* **Boundary particles** are static: sorted into the same cells once, at build.
* **Scalar pair loops.** Every loop over a particle's neighbours (list or cells) in this family starts with
  ``if j < 0: break``, a test that never holds. Taichi compiles with fast math, which lets LLVM 15 reorder a
  pair loop's sums and vectorise it with gather loads (``vpgatherdd``) where the host CPU's model says
  gathers are cheap (Intel Xeons); there they are not: on the Intel Xeon of docs/PERFORMANCE_SPH.md
  (2026-11-28) a DFSPH iteration's pass took 1.46 ms vectorised and 0.61 ms scalar (1 thread, 6,859
  particles), and a stand-alone C loop compiled with ``-march=native`` ran 3x slower than with generic
  tuning. A loop with an exit is not vectorised, so the loop stays scalar on every CPU, and its sums are
  taken in list order (the same on every CPU, where the vector width used to decide the order). Turning
  fast math off (``ti.init(fast_math=False)``) also keeps these loops scalar (3.9 ns per pair against 3.8
  with the exit, stand-alone) but changes every family's arithmetic (no reordering or fused multiply-adds
  anywhere), so the exit is placed per loop instead; tests/unit/test_no_gather_loops.py checks the compiled
  kernels for gathers.
"""

from __future__ import annotations

import numpy as np

# numpy only, used by the Taichi-free memory estimate too: it lives in the family's resources.py
from simcli.solvers.sph.resources import neighbour_capacity  # noqa: F401 - re-exported (solver.py)

CELLS_PER_SUPPORT = 2
BLOCK = 256  # cells per block of the prefix sum


class CellGrid:
    """Geometry of the cell grid: ``origin``, ``cell`` size, ``dims`` (cells per axis, x fastest)."""

    def __init__(self, lo, hi, support: float, dim: int) -> None:
        self.dim = dim
        self.R = CELLS_PER_SUPPORT
        self.cell = support / self.R
        self.pad = self.R + 1  # boundary layers reach one support outside the domain, plus the stencil
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        inner = np.ceil((hi - lo) / self.cell - 1e-9).astype(np.int64)
        self.dims = tuple(int(c + 2 * self.pad) for c in inner)
        self.origin = lo - self.pad * self.cell
        self.ncells = int(np.prod(self.dims))
        self.nblocks = (self.ncells + BLOCK - 1) // BLOCK

    def cell_index_np(self, x: np.ndarray) -> np.ndarray:
        c = np.floor((x - self.origin) / self.cell).astype(np.int64)
        c = np.clip(c, 0, np.asarray(self.dims) - 1)
        lin = c[:, 0].copy()
        stride = 1
        for a in range(1, self.dim):
            stride *= self.dims[a - 1]
            lin += c[:, a] * stride
        return lin

    def inside_np(self, x: np.ndarray) -> np.ndarray:
        """Points that lie in the grid's box (boundary particles beyond it can touch no liquid)."""
        ext = self.origin + np.asarray(self.dims) * self.cell
        return np.all((x >= self.origin) & (x < ext), axis=1)

    def dilate(self, flags: np.ndarray) -> np.ndarray:
        """Per cell: whether any cell of its (2R + 1)^dim stencil is flagged (flags per linear cell index)."""
        a = flags.reshape(self.dims[::-1])  # (z,) y, x: x fastest
        out = a.copy()
        for axis in range(a.ndim):
            acc = out.copy()
            for s in range(1, self.R + 1):
                acc |= np.roll(out, s, axis=axis) | np.roll(out, -s, axis=axis)
            out = acc
        return out.reshape(-1)

    def sort_static(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(order, start): a stable sort of static points by cell and the (ncells + 1) start offsets."""
        lin = self.cell_index_np(x)
        order = np.argsort(lin, kind="stable")
        counts = np.bincount(lin, minlength=self.ncells)
        start = np.zeros(self.ncells + 1, np.int64)
        np.cumsum(counts, out=start[1:])
        return order, start


def make_neighbour_funcs(grid: CellGrid, f, serial_count: bool, fields: dict):
    """Taichi funcs of the cell grid: ``sort(n)`` (count, prefix sum, scatter, copy back: top-level loops
    to be called at kernel scope), ``cell_coords(x)`` and ``for_rows`` helpers.

    ``fields``: ``x`` and the lists ``move`` (fields reordered with the particles, each with its temporary
    twin in ``move_tmp``), ``cell_id``, ``rank``, ``count``, ``start``, ``block_sum``.
    """
    from simcli.backend import stdout_to_stderr

    with stdout_to_stderr():
        import taichi as ti

    dim = grid.dim
    dims = grid.dims
    ncells, nblocks = grid.ncells, grid.nblocks
    inv_cell = 1.0 / grid.cell
    origin = ti.Vector(list(grid.origin), dt=f)
    hi_c = ti.Vector([d - 1 for d in dims])
    x = fields["x"]
    cell_id, rank, count, start, block_sum = (
        fields[k] for k in ("cell_id", "rank", "count", "start", "block_sum")
    )
    move, move_tmp = fields["move"], fields["move_tmp"]
    nmove = len(move)

    @ti.func
    def cell_coords(xp):
        c = ti.cast(ti.floor((xp - origin) * inv_cell), ti.i32)
        return ti.min(ti.max(c, 0), hi_c)  # a NaN position lands in a valid cell (memory safety)

    @ti.func
    def linear(c):
        lin = c[0]
        if ti.static(dim >= 2):
            lin += dims[0] * c[1]
        if ti.static(dim == 3):
            lin += dims[0] * dims[1] * c[2]
        return lin

    @ti.func
    def sort(n):
        for c in range(ncells):
            count[c] = 0
        if ti.static(serial_count):
            ti.loop_config(serialize=True)
            for i in range(n):
                c = linear(cell_coords(x[i]))
                cell_id[i] = c
                rank[i] = count[c]
                count[c] += 1
        else:
            for i in range(n):
                c = linear(cell_coords(x[i]))
                cell_id[i] = c
                rank[i] = ti.atomic_add(count[c], 1)
        for b in range(nblocks):
            s = 0
            for c in range(b * BLOCK, ti.min((b + 1) * BLOCK, ncells)):
                s += count[c]
            block_sum[b] = s
        ti.loop_config(serialize=True)
        for _ in range(1):  # exclusive scan of the block sums, in place (one task)
            acc = 0
            for k in range(nblocks):
                t = block_sum[k]
                block_sum[k] = acc
                acc += t
            start[ncells] = acc
        for b in range(nblocks):
            s = block_sum[b]
            for c in range(b * BLOCK, ti.min((b + 1) * BLOCK, ncells)):
                start[c] = s
                s += count[c]
        for i in range(n):
            slot = start[cell_id[i]] + rank[i]
            for k in ti.static(range(nmove)):
                move_tmp[k][slot] = move[k][i]
        for i in range(n):
            for k in ti.static(range(nmove)):
                move[k][i] = move_tmp[k][i]

    return sort, cell_coords, linear
