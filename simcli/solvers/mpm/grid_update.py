"""Grid update: node momentum -> node velocity, gravity, then the boundary conditions.

Over the nodes of the flagged blocks (blocks.py: the blocks the particles' stencils touch; every other
node of the grid fields is 0; the loop also zeroes the last substep's other nodes), or without one
over the union of the chunks' node boxes (nodes outside hold stale values; nothing reads them), each node
sums the P2G grid copies whose chunk box holds it (in a fixed order: bitwise reproducible), divides the
momentum by the mass, adds ``dt g``, and then: a node touched by a fixed particle is pinned (velocity 0),
any other gets the walls' and colliders' contact conditions (``boundary.GridBoundary.apply``). Empty nodes
get velocity 0. Under FLIP the node's velocity increment of the substep is stored too (transfer.py);
coupled scenes keep each node's mass in ``grid_m`` for the coupling phase.
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.mpm.fields import MPMFields, MPMParams

with stdout_to_stderr():
    import taichi as ti


def build_grid_update(params: MPMParams, fields: MPMFields, boundary, flip, blocks=None):
    """The ``ti.func`` ``grid_update(dt)``. ``boundary``: an object with a ``ti.func``
    ``apply(I, v, m) -> v``, or boundary.GridBoundary (``bind_grid`` and ``apply(I, v, m, dt, xm)``);
    ``flip``: transfer.FlipTransfer or None (APIC); ``blocks``: blocks.BlockList (the nodes of the blocks
    that hold material) or None (every node of the particles' box).
    Reads grid, bbox, gravity; writes bbox_all, grid_v (and grid_m when allocated)."""
    dim, f, T, gdim, has_fixed = params.dim, params.dtype, params.T, params.gdim, params.has_fixed
    gap_ch, gap_aff = params.gap_ch, params.gap_aff
    grid, grid_v, grid_m = fields.grid, fields.grid_v, fields.grid_m
    bbox, bbox_all, gravity = fields.bbox, fields.bbox_all, fields.gravity
    keep_m = grid_m is not None
    # GridBoundary's colliders read the P2G copies (their image) and take dt; a plain boundary object
    # (apply(I, v, m) only, as the operator tests build) neither
    with_grid = hasattr(boundary, "bind_grid")
    if with_grid:
        boundary.bind_grid(grid, bbox, T, gravity, gap_ch)
    use_flip = flip is not None
    use_blocks = blocks is not None

    @ti.func
    def node_update(I, dt):
        g = ti.Vector.zero(f, gdim)
        if ti.static(T == 1):
            g = grid[0, I]
        else:
            for t in ti.static(range(T)):
                a = bbox[t, 0]
                b = bbox[t, 1]
                inside = True
                for d in ti.static(range(dim)):
                    inside = inside and a[d] <= I[d] and I[d] < b[d]
                if inside:  # outside its chunk's box a copy holds stale values
                    g += grid[t, I]
        m = g[dim]
        vI = ti.Vector.zero(f, dim)
        if m > 0:
            for d in ti.static(range(dim)):
                vI[d] = g[d] / m
            vI += dt * gravity[None]
            pinned = False
            if ti.static(has_fixed):
                pinned = g[dim + 1] > 0
            if pinned:
                vI = ti.Vector.zero(f, dim)
            else:
                if ti.static(with_grid):
                    xm = ti.Vector.zero(f, dim)  # the node's material position (gap test)
                    if ti.static(gap_ch >= 0):
                        for d in ti.static(range(dim)):
                            xm[d] = g[gap_ch + d] / m
                    va = ti.Vector.zero(f, dim)  # the node's affine velocity (APIC), see boundary._node
                    if ti.static(gap_aff):
                        for d in ti.static(range(dim)):
                            va[d] = g[gap_ch + dim + d] / m
                    vI = boundary.apply(I, vI, m, dt, xm, va)
                else:
                    vI = boundary.apply(I, vI, m)
        grid_v[I] = vI
        if ti.static(keep_m):
            grid_m[I] = m
        if ti.static(use_flip):
            flip.store(I, g, vI)

    block_update = blocks.make_update(node_update) if use_blocks else None

    @ti.func
    def grid_update(dt):
        pa = bbox_all[0]  # the last substep's node box (the block list zeroes what it wrote there)
        pb = bbox_all[1]
        lo = bbox[0, 0]
        hi = bbox[0, 1]
        for t in ti.static(range(1, T)):
            lo = ti.min(lo, bbox[t, 0])
            hi = ti.max(hi, bbox[t, 1])
        bbox_all[0] = lo
        bbox_all[1] = hi
        a = bbox_all[0]
        b = bbox_all[1]
        if ti.static(use_blocks):  # the marked blocks' nodes (blocks.py): the rest are 0
            block_update(dt, pa, pb, a, b)
        elif ti.static(dim == 3):
            for i, j, k in ti.ndrange((a[0], b[0]), (a[1], b[1]), (a[2], b[2])):
                node_update(ti.Vector([i, j, k]), dt)
        else:
            for i, j in ti.ndrange((a[0], b[0]), (a[1], b[1])):
                node_update(ti.Vector([i, j]), dt)

    return grid_update
