"""G2P, grid to particle: gather the new velocity and its gradient, update F, return-map, advect.

Per particle: v = sum_i w_i v_i and C = D^-1 sum_i w_i v_i (x_i - x_p)^T (APIC; under FLIP the new velocity
blends in the particle's own one, transfer.py); F <- (I + dt C) F, kept as H = F - I; the plastic laws'
return mapping (``return_mapping`` in plasticity.py / fluid_muscle.py) projects F, for the materials that
have one; x <- x + dt v_grid; a particle that ended inside a collider goes back to its surface; positions
are clamped to the domain. Fixed particles keep v = 0, C = 0 and do not move.

The same particle loop also computes each chunk's node box [lo, hi) from the new positions (into
``bbox``, on the device): the next substep's clear and grid update sweep only those nodes. ``node_boxes()``
computes the boxes without moving anything (after a state upload or emission).
"""

from dataclasses import dataclass
from typing import Any

from simcli.backend import stdout_to_stderr
from simcli.solvers.mpm.blocks import build_mark
from simcli.solvers.mpm.fields import CHUNK_STRIDE, MPMFields, MPMParams
from simcli.solvers.mpm.stencil import Stencil, chunk_of

with stdout_to_stderr():
    import taichi as ti


@dataclass(frozen=True)
class G2P:
    """``g2p(dt)``: move every particle and recompute the node boxes; ``node_boxes()``: the boxes only.
    Both are ``ti.func``: call them from a kernel."""

    g2p: Any
    node_boxes: Any


def build_g2p(
    params: MPMParams, fields: MPMFields, stencil: Stencil, laws: list, boundary, flip, count, cpic=None
) -> G2P:
    """``laws``: the solver's constitutive laws (index = law id, see fields.MPMFields.mat_law_id); those with
    ``plastic`` set have their ``return_mapping`` compiled in. ``boundary``: boundary.GridBoundary
    (``n_colliders``, ``project_particle``); ``flip``: transfer.FlipTransfer or None; ``count``: ti.func,
    the particle loop's bound; ``cpic``: cpic.CPIC or None (the nodes across a CPIC collider give the
    particle its ghost velocity). Reads grid_v, chunk_start; writes x, v, C, F, bbox (and the laws' state)."""
    use_cpic = cpic is not None
    dim, f, T, chunked, has_fixed = params.dim, params.dtype, params.T, params.chunked, params.has_fixed
    inv_dx = params.inv_dx
    N = count
    x, v, C, F, mass, mid, fixed = (
        fields.x,
        fields.v,
        fields.C,
        fields.F,
        fields.mass,
        fields.mid,
        fields.fixed,
    )
    grid_v, bbox, chunk_start = fields.grid_v, fields.bbox, fields.chunk_start
    mat_mu, mat_lam, mat_law_id = fields.mat_mu, fields.mat_lam, fields.mat_law_id
    use_flip = flip is not None
    n_laws = len(laws)
    any_plastic = any(law.plastic for law in laws)
    dom_lo = ti.Vector(list(params.domain_lo), dt=f)
    dom_hi = ti.Vector(list(params.domain_hi), dt=f)
    big = 1 << 30
    marking = params.block_list  # flag the next P2G's blocks where the node boxes are made (blocks.py)
    mark_blocks = build_mark(params, fields.blocks) if marking else None
    bspline, base_node = stencil.bspline, stencil.base_node

    @ti.func
    def node_v(node, mask, o: ti.template()):
        """grid_v at a stencil node, 0 across a CPIC collider (its ghost node's part is added after the
        stencil loop, cpic.py)."""
        return grid_v[node] * cpic.keep(mask, o)

    @ti.func
    def g2p_particle(p, dt):
        base, fx, w = bspline(x[p])
        mask = 0
        jj = -1
        vg = ti.Vector.zero(f, dim)
        if ti.static(use_cpic):
            mask, _W, _M1, vg, jj = cpic.classify(x[p], fx, v[p])
        new_v = ti.Vector.zero(f, dim)
        b = [ti.Vector.zero(f, dim) for _ in ti.static(range(dim))]  # columns of sum w v i^T
        for i in ti.static(range(3)):
            for j in ti.static(range(3)):
                wij = w[i][0] * w[j][1]
                s0 = ti.Vector.zero(f, dim)  # sum_k w_k v
                s1 = ti.Vector.zero(f, dim)  # sum_k w_k k v
                if ti.static(dim == 2 and use_cpic):
                    s0 = node_v(base + ti.Vector([i, j]), mask, i * 3 + j)
                elif ti.static(dim == 2):
                    s0 = grid_v[base[0] + i, base[1] + j]
                else:
                    for k in ti.static(range(3)):
                        gk = ti.Vector.zero(f, dim)
                        if ti.static(use_cpic):
                            gk = node_v(base + ti.Vector([i, j, k]), mask, i * 9 + j * 3 + k)
                        else:
                            gk = grid_v[base[0] + i, base[1] + j, base[2] + k]
                        g = w[k][2] * gk
                        s0 += g
                        if ti.static(k > 0):
                            s1 += g * k
                t0 = wij * s0
                new_v += t0
                if ti.static(i > 0):
                    b[0] += t0 * i
                if ti.static(j > 0):
                    b[1] += t0 * j
                if ti.static(dim == 3):
                    b[2] += wij * s1
        B = ti.Matrix.cols(b)
        if ti.static(use_cpic):
            if mask != 0:  # the nodes across a CPIC collider: their ghost nodes' velocities (cpic.py)
                gs, gb = cpic.ghost_sum(base, fx, mask, x[p], vg, jj, dt)
                new_v += gs
                B += gb
                cpic.add_load(jj, x[p], -mass[p] * gs)  # the momentum they give back: the collider's
        # C = D^-1 sum_i w_i v_i (x_i - x_p)^T = (4 / dx) (sum_i w_i v_i i^T - v fx^T)
        new_C = (4.0 * inv_dx) * (B - new_v.outer_product(fx))
        is_fixed = False
        if ti.static(has_fixed):
            is_fixed = fixed[p] != 0
        if is_fixed:
            v[p] = ti.Vector.zero(f, dim)
            C[p] = ti.Matrix.zero(f, dim, dim)
        else:
            # F_new = (I + dt C) F, kept as H_new = H + dt C (I + H) (see build: F stores H)
            Hp = F[p]
            Hp = Hp + dt * (new_C @ (ti.Matrix.identity(f, dim) + Hp))
            if ti.static(any_plastic):
                m = mid[p]
                for k in ti.static(range(n_laws)):
                    if ti.static(laws[k].plastic):  # noqa: SIM102 - compile-time, then run-time test
                        if ti.static(n_laws == 1) or mat_law_id[m] == k:
                            Fp = laws[k].return_mapping(
                                p, ti.Matrix.identity(f, dim) + Hp, m, mat_mu[m], mat_lam[m]
                            )
                            Hp = Fp - ti.Matrix.identity(f, dim)
            F[p] = Hp
            v_grid = new_v  # positions move with the grid velocity under both transfers
            if ti.static(use_flip):
                new_v = flip.blend(v[p], v_grid, flip.gather(base, w))
            xp = x[p] + dt * v_grid
            if ti.static(boundary.n_colliders > 0):
                # a particle that ended inside a collider goes back to its surface (the grid
                # contact alone lets particles that start inside, or tunnel, stay there)
                xp, new_v = boundary.project_particle(xp, new_v, mass[p])
            if ti.static(use_cpic):  # no particle crosses a thin CPIC Box
                xp, new_v = cpic.keep_side(x[p], xp, new_v, mass[p])
            xp = ti.min(ti.max(xp, dom_lo), dom_hi)
            v[p] = new_v
            C[p] = new_C
            x[p] = xp

    @ti.func
    def particle_base(p):
        return base_node(x[p])

    @ti.func
    def particle_pass(dt, move: ti.template()):
        """The node box [lo, hi) of each chunk's particles (of all of them without chunks), after
        moving each particle by g2p first when ``move``."""
        if ti.static(chunked):
            for j in range(T * CHUNK_STRIDE):
                t = chunk_of(j)
                if t >= 0:
                    lo = ti.Vector([big] * dim)
                    hi = ti.Vector([-big] * dim)
                    for p in range(chunk_start[t], chunk_start[t + 1]):
                        if ti.static(move):
                            g2p_particle(p, dt)
                        bp = particle_base(p)
                        if ti.static(marking):
                            mark_blocks(bp)
                        lo = ti.min(lo, bp)
                        hi = ti.max(hi, bp)
                    bbox[t, 0] = lo
                    bbox[t, 1] = hi + 3
        else:
            bbox[0, 0] = ti.Vector([big] * dim)
            bbox[0, 1] = ti.Vector([-big] * dim)
            for p in range(N()):
                if ti.static(move):
                    g2p_particle(p, dt)
                bp = particle_base(p)
                if ti.static(marking):
                    mark_blocks(bp)
                for d in ti.static(range(dim)):
                    ti.atomic_min(bbox[0, 0][d], bp[d])
                    ti.atomic_max(bbox[0, 1][d], bp[d] + 3)

    @ti.func
    def g2p(dt):
        particle_pass(dt, True)

    @ti.func
    def node_boxes():
        particle_pass(0.0, False)

    return G2P(g2p, node_boxes)
