"""The MPM substep's kernels, composed from the operator modules in the paper's order::

    clear_grid -> p2g -> grid_update -> g2p          (p2g.py, grid_update.py, g2p.py)

``substep`` runs them in one kernel launch (each top-level loop is one parallel task; on the CPU every
launch and every task costs tens of microseconds). Coupled scenes split it around the coupling phase
(``pre_couple``: up to the updated grid velocities, which the coupling edits; then ``stage_g2p``). The
single stages are also kernels of their own, for tests and profiling.

Everything is built from the explicit bundle (fields.py) and the pluggable pieces: laws, boundary, FLIP
transfer, particle count. Nothing here reads the solver.
"""

from dataclasses import dataclass
from typing import Any

from simcli.backend import stdout_to_stderr
from simcli.solvers.mpm.blocks import build_block_list
from simcli.solvers.mpm.fields import MPMFields, MPMParams
from simcli.solvers.mpm.g2p import build_g2p
from simcli.solvers.mpm.grid_update import build_grid_update
from simcli.solvers.mpm.laws import build_law_dispatch
from simcli.solvers.mpm.outputs import build_derive, build_frame_stats, build_outputs
from simcli.solvers.mpm.p2g import build_p2g
from simcli.solvers.mpm.stencil import build_stencil

with stdout_to_stderr():
    import taichi as ti


@dataclass(frozen=True)
class MPMKernels:
    """The solver's kernels: ``substep(dt)``, ``pre_couple(dt)``, ``stage_p2g(dt)``,
    ``stage_grid_update(dt)``, ``stage_g2p(dt)``, ``compute_bbox()`` (node boxes after a state change),
    ``frame_stats()``, ``make_outputs(out)`` building the derived-outputs kernel on first use, and
    ``make_derive(out)`` its per-particle ti.func (the probes' device path)."""

    substep: Any
    pre_couple: Any
    stage_p2g: Any
    stage_grid_update: Any
    stage_g2p: Any
    compute_bbox: Any
    frame_stats: Any
    make_outputs: Any
    make_derive: Any = None


def build_kernels(
    params: MPMParams, fields: MPMFields, laws: list, boundary, flip, count, cpic=None
) -> MPMKernels:
    """``laws``: the constitutive laws (index = law id); ``boundary``: boundary.GridBoundary; ``flip``:
    transfer.FlipTransfer or None (APIC); ``count``: ti.func, the particle loops' bound; ``cpic``:
    cpic.CPIC or None (no CPIC collider: nothing of it compiled)."""
    f = params.dtype
    stencil = build_stencil(params)
    dispatch = build_law_dispatch(
        params.dim, f, laws, fields.mid, fields.mat_mu, fields.mat_lam, fields.mat_law_id
    )
    blocks = None
    if (
        params.block_list
    ):  # zero what the last substep wrote (all gdim channels, CPIC's ghosts too), take G2P's marks
        blocks = build_block_list(params, fields, fields.blocks, flip)
    chunk_clear = blocks.clear_copy if blocks is not None and params.chunked else None
    ops_p2g = build_p2g(params, fields, stencil, dispatch.kirchhoff, flip, count, chunk_clear, cpic)
    p2g = ops_p2g.p2g
    clear_grid = blocks.prepare if blocks is not None else ops_p2g.clear_grid
    grid_update = build_grid_update(params, fields, boundary, flip, blocks)
    ops_g2p = build_g2p(params, fields, stencil, laws, boundary, flip, count, cpic)
    g2p, node_boxes = ops_g2p.g2p, ops_g2p.node_boxes

    @ti.kernel
    def substep(dt: f):
        # one launch per substep: each top-level loop below is one parallel task, and on the
        # CPU every kernel launch and every parallel task costs tens of microseconds
        clear_grid()
        p2g(dt)
        grid_update(dt)
        g2p(dt)

    # the same stages one kernel each, for tests and profiling (not on the hot path)
    @ti.kernel
    def stage_p2g(dt: f):
        clear_grid()
        p2g(dt)

    @ti.kernel
    def stage_grid_update(dt: f):
        grid_update(dt)

    @ti.kernel
    def stage_g2p(dt: f):
        g2p(dt)

    @ti.kernel
    def pre_couple(dt: f):
        # coupled scenes: the substep up to the updated grid velocities (the coupling phase edits them)
        clear_grid()
        p2g(dt)
        grid_update(dt)

    @ti.kernel
    def compute_bbox():
        node_boxes()

    frame_stats = build_frame_stats(params, fields, laws, dispatch, count)

    def make_outputs(out):
        return build_outputs(params, fields, dispatch, count, out)

    def make_derive(out):
        return build_derive(params, fields, dispatch, out)

    return MPMKernels(
        substep=substep,
        pre_couple=pre_couple,
        stage_p2g=stage_p2g,
        stage_grid_update=stage_grid_update,
        stage_g2p=stage_g2p,
        compute_bbox=compute_bbox,
        frame_stats=frame_stats,
        make_outputs=make_outputs,
        make_derive=make_derive,
    )
