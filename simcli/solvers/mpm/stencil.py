"""What P2G and G2P share: the quadratic B-spline stencil of a particle (its base node, fractional
position and weights per axis) and the particle chunks of the private-copy P2G.

The stencil loops of P2G and G2P are written as nested static loops over plain ints with the
offset-dependent parts hoisted (q_i, q_ij, w_i w_j): Taichi compiles that several times faster than a
loop over ti.grouped offset vectors, and it does fewer flops.
"""

from dataclasses import dataclass
from typing import Any

from simcli.backend import stdout_to_stderr
from simcli.solvers.mpm.fields import CHUNK_STRIDE, MPMParams

with stdout_to_stderr():
    import taichi as ti


@ti.func
def chunk_of(j):
    """Chunk index of outer iteration j, or -1 (see CHUNK_STRIDE)."""
    t = -1
    if j % CHUNK_STRIDE == 0:
        t = j // CHUNK_STRIDE
    return t


@dataclass(frozen=True)
class Stencil:
    """``base_node(x)``: the stencil's first node (int vector); ``bspline(x)``: (base, fx, w) with fx the
    position in cells relative to base and w[i][d] the weight of node base + i along axis d;
    ``cols(M)``: the columns of a dim x dim matrix as a list of vectors."""

    base_node: Any
    bspline: Any
    cols: Any


def build_stencil(params: MPMParams) -> Stencil:
    f, dim = params.dtype, params.dim
    inv_dx = params.inv_dx
    origin = ti.Vector(list(params.origin), dt=f)
    base_max = ti.Vector([s - 3 for s in params.grid_shape])  # the stencil is base .. base + 2

    @ti.func
    def base_node(xp):
        # floor (Xp >= PAD > 0.5 for positions in the domain); the clamp only matters for a
        # NaN/inf position, which then stays inside the grid arrays (memory safety) while its
        # NaN weights show up in the next frame check
        b = ti.cast((xp - origin) * inv_dx - 0.5, ti.i32)
        return ti.min(ti.max(b, 0), base_max)

    @ti.func
    def bspline(xp):
        Xp = (xp - origin) * inv_dx
        base = base_node(xp)
        fx = Xp - ti.cast(base, f)
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
        return base, fx, w

    @ti.func
    def cols(M):
        return [ti.Vector([M[r, c] for r in ti.static(range(dim))]) for c in ti.static(range(dim))]

    return Stencil(base_node, bspline, cols)
