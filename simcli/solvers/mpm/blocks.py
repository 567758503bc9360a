"""The block list: MPM's per-substep grid work over the blocks of nodes that hold material, not over the box
around all particles.

The grid is divided into blocks of ``edge^dim`` nodes (``BLOCK_EDGE``: 4^3 = 64 nodes in 3D, 8^2 in 2D).
Before P2G, ``prepare()`` runs three passes in two parallel loops (plain Taichi: the same code on the CPU
and CUDA; 1 and 2 share a loop, as each loop is a task that costs tens of microseconds on the CPU):

1. **zero the last substep's blocks**: the nodes of the blocks in the list (the blocks the previous P2G
   wrote) inside the previous substep's node box (``bbox_all``, which holds every node that substep
   wrote) are set to 0 in every P2G grid copy, in ``grid_v`` and, where allocated, in ``grid_m`` and
   FLIP's ``grid_dv``. Every other node is zero already (by induction: the
   fields start at 0, and only such nodes are ever written: P2G writes its particles' stencils, the grid
   update the list's nodes in the box, the coupling phase nodes of positive mass), so after this pass every
   grid field is 0 everywhere;
2. **mark**: each particle flags the (at most 2^dim) blocks its 3^dim stencil touches (base .. base + 2,
   the same ``base_node`` as P2G: no edit to P2G's scatter);
3. **compact**: a loop over the block flags appends the flagged blocks to the list (an atomic counter;
   the order of the list is whatever the threads make of it, which only changes the order in which the
   nodes are visited: each node's own sums are unchanged) and resets the flags.

The grid update then visits the list's nodes inside the particles' node box only (``n_nodes()``,
``node(q, lo, hi)``: never more nodes than the box sweep, so a compact body pays only the two passes).
Since every grid field is 0 off the list, a node of the box outside the list holds exactly what the box
sweep wrote there (velocity 0, mass 0, FLIP increment 0): the loops that still sweep the box (the coupling
phase's, simcli/coupling/grid_contact.py; the colliders' image reads of the copies, boundary.py) see the
same numbers. Cost: a pass over the particles' positions and one over the block flags, against the box's clear
and update; the list holds at most every block of the grid (``prod(ceil(grid_shape / edge))`` entries).
"""

from __future__ import annotations

import math
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
    """``flag`` (i32 per block: touched by a particle's stencil this substep), ``blocks`` (the list: block
    index vectors, the first ``count[None]`` valid), ``count`` (0-d i32)."""

    edge: int
    flag: Any
    blocks: Any
    count: Any

    @classmethod
    def allocate(cls, dim: int, grid_shape: tuple, edge: int | None = None) -> BlockFields:
        edge = BLOCK_EDGE[dim] if edge is None else int(edge)
        bshape = block_shape(grid_shape, edge)
        return cls(
            edge=edge,
            flag=ti.field(ti.i32, shape=bshape),
            blocks=ti.Vector.field(dim, ti.i32, shape=math.prod(bshape)),
            count=ti.field(ti.i32, shape=()),
        )

    def nodes(self, base: np.ndarray, lo, hi) -> int:
        """The nodes a grid update visits for particles whose stencils start at the nodes ``base`` (n x dim):
        those of the blocks the stencils touch inside the node box [lo, hi) (host-side, for counts)."""
        if len(base) == 0:
            return 0
        base = np.asarray(base, dtype=np.int64)
        b0, b1 = base // self.edge, (base + 2) // self.edge
        dim = base.shape[1]
        # the 2^dim blocks of each stencil (as the marking pass), without repeats
        picks = [np.where([(c >> d) & 1 for d in range(dim)], b1, b0) for c in range(2**dim)]
        b = np.unique(np.concatenate(picks), axis=0) * self.edge
        lo, hi = np.asarray(lo, dtype=np.int64), np.asarray(hi, dtype=np.int64)
        ext = np.minimum(b + self.edge, hi) - np.maximum(b, lo)
        return int(np.prod(np.maximum(ext, 0), axis=1).sum())


@dataclass(frozen=True)
class BlockList:
    """``prepare()``: zero the last substep's blocks, then mark and compact this substep's (call before
    P2G); ``n_nodes()``: the grid update's loop bound; ``node(q, lo, hi)``: the list's q-th node and whether
    it lies in the node box [lo, hi). All ``ti.func``."""

    prepare: Any
    n_nodes: Any
    node: Any


def build_block_list(params, fields, bf: BlockFields, base_node, flip, count) -> BlockList:
    """``params``/``fields``: fields.MPMParams/MPMFields; ``bf``: the block fields; ``base_node``: the
    stencil's first node (stencil.Stencil.base_node); ``flip``: transfer.FlipTransfer or None; ``count``:
    ti.func, the particle loops' bound."""
    dim, f, T, gdim = params.dim, params.dtype, params.T, params.gdim
    E = bf.edge
    BS = E**dim
    grid, grid_v, grid_m, x, bbox_all = fields.grid, fields.grid_v, fields.grid_m, fields.x, fields.bbox_all
    keep_m = grid_m is not None
    use_flip = flip is not None
    flag, blocks, nblk = bf.flag, bf.blocks, bf.count
    N = count

    @ti.func
    def node(q, lo, hi):
        b = blocks[q // BS]
        r = q % BS
        off = ti.Vector.zero(ti.i32, dim)
        for d in ti.static(range(dim)):  # last axis fastest, as the dense layout
            off[dim - 1 - d] = r % E
            r = r // E
        I = b * E + off
        ok = True
        for d in ti.static(range(dim)):
            ok = ok and lo[d] <= I[d] and I[d] < hi[d]
        return I, ok

    @ti.func
    def n_nodes():
        return nblk[None] * BS

    @ti.func
    def prepare():
        # two parallel tasks (on the CPU each task costs tens of microseconds: B1's whole substep is ~1 ms)
        lo = bbox_all[0]  # the last substep's node box: it holds every node the last substep wrote
        hi = bbox_all[1]
        nclear = nblk[None] * BS  # (bounds are read before the loop runs: the reset below is safe)
        for q in range(nclear + N()):
            if q == 0:
                nblk[None] = 0
            if q < nclear:  # 1. the nodes the last substep wrote back to 0
                I, ok = node(q, lo, hi)
                if ok:
                    for t in ti.static(range(T)):
                        grid[t, I] = ti.Vector.zero(f, gdim)
                    grid_v[I] = ti.Vector.zero(f, dim)
                    if ti.static(keep_m):
                        grid_m[I] = 0.0
                    if ti.static(use_flip):
                        flip.grid_dv[I] = ti.Vector.zero(f, dim)
            else:  # 2. the blocks this substep's stencils touch
                b0 = base_node(x[q - nclear])
                b1 = (b0 + 2) // E
                b0 = b0 // E
                for c in ti.static(range(2**dim)):
                    b = b0
                    for d in ti.static(range(dim)):
                        if ti.static((c >> d) & 1):
                            b[d] = b1[d]
                    flag[b] = 1
        for b in ti.grouped(flag):  # 3. compact; the flags go back to 0 for the next substep
            if flag[b] != 0:
                k = ti.atomic_add(nblk[None], 1)
                blocks[k] = b
                flag[b] = 0

    return BlockList(prepare, n_nodes, node)
