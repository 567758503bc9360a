"""The block flags: MPM's per-substep grid work over the blocks of nodes that hold material, not over the box
around all particles.

The grid is divided into blocks of ``edge^dim`` nodes (``BLOCK_EDGE``: 4^3 = 64 nodes in 3D, 8^2 in 2D).
Two flags per block, no list and no extra pass over the particles:

* ``mark`` (the blocks the *next* P2G writes): set wherever the node box of the particles is computed, i.e.
  in G2P's particle loop right after a particle's new position gives its next stencil (``mark(base)``: the
  at most 2^dim blocks of the 3^dim stencil base .. base + 2, the same ``base_node`` as P2G), and in
  ``node_boxes`` (g2p.py), which every change of the particle set outside G2P already calls (build,
  emitters and sinks: ``MPMSolver.active_changed``), so newly emitted particles mark their blocks before
  the next P2G, and coupled scenes (``pre_couple`` / ``post_couple``) mark in their G2P as well;
* ``used`` (the blocks the *last* P2G wrote, then this substep's).

``prepare()`` (before P2G, one parallel loop over the block flags) zeroes the nodes of the ``used`` blocks
inside the previous substep's node box (``bbox_all``, which holds every node that substep wrote) in every
P2G grid copy, in ``grid_v`` and, where allocated, in ``grid_m`` and FLIP's ``grid_dv``; then it moves
``mark`` to ``used`` and resets ``mark``. Every other node is zero already (by induction: the fields start
at 0, and only such nodes are ever written: P2G writes its particles' stencils, the grid update the
``used`` blocks' nodes in the box, the coupling phase nodes of positive mass), so after this loop every grid
field is 0 everywhere. The grid update then walks the ``used`` blocks' nodes inside the particles' node box
(``span``: each block clipped to the box; never more nodes than the box sweep).
Since every grid field is 0 off these blocks, a node of the box outside them holds exactly what the box
sweep wrote there (velocity 0, mass 0, FLIP increment 0): the loops that still sweep the box (the coupling
phase's, simcli/coupling/grid_contact.py; the colliders' image reads of the copies, boundary.py) see the
same numbers. Cost against the box sweep: one extra loop over the block flags (``prod(ceil(grid_shape /
edge))`` entries) and 2^dim flag stores per particle in G2P; the grid update visits the blocks in any order,
which changes no node's own sums (bit for bit the box sweep's results).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti

BLOCK_EDGE = {2: 8, 3: 4}  # nodes per block edge: 64 nodes a block in both


def block_shape(grid_shape: tuple, edge: int) -> tuple:
    """Blocks per axis covering ``grid_shape`` nodes (the last block of an axis may be partial)."""
    return tuple(-(-int(s) // edge) for s in grid_shape)


@dataclass
class BlockFields:
    """``mark`` (i32 per block: the next P2G's stencils touch it), ``used`` (i32 per block: the last P2G's
    until the grid update, then this substep's), ``wrote`` (per P2G copy, the box the last P2G wrote)."""

    edge: int
    mark: Any
    used: Any
    wrote: Any  # per P2G copy t: the node box [lo, hi) the last P2G wrote that copy in (a chunk's box)

    @classmethod
    def allocate(cls, dim: int, grid_shape: tuple, T: int = 1, edge: int | None = None) -> BlockFields:
        edge = BLOCK_EDGE[dim] if edge is None else int(edge)
        bshape = block_shape(grid_shape, edge)
        return cls(
            edge=edge,
            mark=ti.field(ti.i32, shape=bshape),
            used=ti.field(ti.i32, shape=bshape),
            wrote=ti.Vector.field(dim, ti.i32, shape=(T, 2)),
        )

    def nodes(self, base: np.ndarray, lo, hi) -> int:
        """The nodes a grid update visits for particles whose stencils start at the nodes ``base`` (n x dim):
        those of the blocks the stencils touch inside the node box [lo, hi) (host-side, for counts)."""
        if len(base) == 0:
            return 0
        base = np.asarray(base, dtype=np.int64)
        b0, b1 = base // self.edge, (base + 2) // self.edge
        dim = base.shape[1]
        # the 2^dim blocks of each stencil (as the marking), without repeats
        picks = [np.where([(c >> d) & 1 for d in range(dim)], b1, b0) for c in range(2**dim)]
        b = np.unique(np.concatenate(picks), axis=0) * self.edge
        lo, hi = np.asarray(lo, dtype=np.int64), np.asarray(hi, dtype=np.int64)
        ext = np.minimum(b + self.edge, hi) - np.maximum(b, lo)
        return int(np.prod(np.maximum(ext, 0), axis=1).sum())


def build_mark(params, bf: BlockFields):
    """``mark(base)``: ti.func flagging the blocks of the stencil that starts at node ``base`` for the next
    P2G (plain stores of 1: concurrent writers write the same value)."""
    dim, E, mark = params.dim, bf.edge, bf.mark

    @ti.func
    def do_mark(base):
        b1 = (base + 2) // E
        b0 = base // E
        for c in ti.static(range(2**dim)):
            b = b0
            for d in ti.static(range(dim)):
                if ti.static((c >> d) & 1):
                    b[d] = b1[d]
            mark[b] = 1  # (a read before the store changed the G2P loop's code: last-bit velocities)

    return do_mark


@dataclass(frozen=True)
class BlockList:
    """``prepare()``: without chunks, zero the copy the last P2G wrote (call before P2G; a no-op with
    chunks); ``clear_copy(t)``: with chunks, the same for copy t, serially in chunk t's P2G task;
    ``make_update(node_update)`` (Python) -> ``update(dt, plo, phi, lo, hi)``: the grid update over the
    blocks (``node_update(I, dt)`` per node), which also zeroes the last substep's other nodes and hands
    the marks over. The others are ``ti.func``."""

    prepare: Any
    clear_copy: Any
    make_update: Any


def build_block_list(params, fields, bf: BlockFields, flip) -> BlockList:
    """``params``/``fields``: fields.MPMParams/MPMFields; ``bf``: the block fields; ``flip``:
    transfer.FlipTransfer or None."""
    dim, f, gdim, chunked = params.dim, params.dtype, params.gdim, params.chunked
    E = bf.edge
    grid, grid_v, grid_m = fields.grid, fields.grid_v, fields.grid_m
    bbox, bbox_all = fields.bbox, fields.bbox_all
    keep_m = grid_m is not None
    use_flip = flip is not None
    mark, used, wrote = bf.mark, bf.used, bf.wrote

    @ti.func
    def span(b, lo, hi):
        """Block b's nodes inside the node box [lo, hi): [a, c) per axis (empty where c <= a)."""
        return ti.max(b * E, lo), ti.min(b * E + E, hi)

    @ti.func
    def zero_copy(t, b, lo, hi):
        u, w = span(b, lo, hi)
        if ti.static(dim == 3):
            for i in range(u[0], w[0]):
                for j in range(u[1], w[1]):
                    for k in range(u[2], w[2]):
                        grid[t, i, j, k] = ti.Vector.zero(f, gdim)
        else:
            for i in range(u[0], w[0]):
                for j in range(u[1], w[1]):
                    grid[t, i, j] = ti.Vector.zero(f, gdim)

    @ti.func
    def zero_node(I):
        grid_v[I] = ti.Vector.zero(f, dim)
        if ti.static(keep_m):
            grid_m[I] = 0.0
        if ti.static(use_flip):
            flip.grid_dv[I] = ti.Vector.zero(f, dim)

    @ti.func
    def clear_copy(t):
        """Serial (chunk t's P2G task): copy t back to 0 where the last P2G wrote it (the ``used`` blocks
        in its box), then remember this P2G's box (the chunk's node box)."""
        lo = wrote[t, 0]
        hi = wrote[t, 1]
        b0 = lo // E
        b1 = (hi + E - 1) // E
        if ti.static(dim == 3):
            for bi in range(b0[0], b1[0]):
                for bj in range(b0[1], b1[1]):
                    for bk in range(b0[2], b1[2]):
                        b = ti.Vector([bi, bj, bk])
                        if used[b] != 0:
                            zero_copy(t, b, lo, hi)
        else:
            for bi in range(b0[0], b1[0]):
                for bj in range(b0[1], b1[1]):
                    b = ti.Vector([bi, bj])
                    if used[b] != 0:
                        zero_copy(t, b, lo, hi)
        wrote[t, 0] = bbox[t, 0]
        wrote[t, 1] = bbox[t, 1]

    @ti.func
    def prepare():
        if ti.static(not chunked):  # one parallel task over the block flags (the GPU's path)
            lo = bbox_all[0]  # the last substep's node box: it holds every node the last substep wrote
            hi = bbox_all[1]
            for b in ti.grouped(used):
                if used[b] != 0:
                    zero_copy(0, b, lo, hi)

    def make_update(node_update):
        """``update(dt, plo, phi, lo, hi)`` for the grid update's ``node_update(I, dt)``."""

        @ti.func
        def update(dt, plo, phi, lo, hi):
            """Over the blocks: the marked ones' nodes in this substep's node box [lo, hi) get
            ``node_update``; the last substep's (``used``) nodes in its box [plo, phi) that this one does not
            update go back to 0 (grid_v, grid_m, FLIP's increment); then ``used`` takes the marks."""
            for b in ti.grouped(used):  # one parallel task
                p = used[b]
                c = mark[b]
                if c != 0:
                    u, w = span(b, lo, hi)
                    if ti.static(dim == 3):
                        for i in range(u[0], w[0]):
                            for j in range(u[1], w[1]):
                                for k in range(u[2], w[2]):
                                    node_update(ti.Vector([i, j, k]), dt)
                    else:
                        for i in range(u[0], w[0]):
                            for j in range(u[1], w[1]):
                                node_update(ti.Vector([i, j]), dt)
                if p != 0:
                    u, w = span(b, plo, phi)
                    covered = c != 0  # the last box's part of the block lies in this box: all updated
                    for d in ti.static(range(dim)):
                        covered = covered and (w[d] <= u[d] or (lo[d] <= u[d] and w[d] <= hi[d]))
                    if not covered:
                        if ti.static(dim == 3):
                            for i in range(u[0], w[0]):
                                for j in range(u[1], w[1]):
                                    for k in range(u[2], w[2]):
                                        I = ti.Vector([i, j, k])
                                        if c == 0 or (I < lo).any() or (I >= hi).any():
                                            zero_node(I)
                        else:
                            for i in range(u[0], w[0]):
                                for j in range(u[1], w[1]):
                                    I = ti.Vector([i, j])
                                    if c == 0 or (I < lo).any() or (I >= hi).any():
                                        zero_node(I)
                if p != c:
                    used[b] = c
                if c != 0:
                    mark[b] = 0

        return update

    return BlockList(prepare, clear_copy, make_update)
