"""The bundle every MPM kernel builder takes: what is compiled in (:class:`MPMParams`) and the Taichi
fields the kernels read and write (:class:`MPMFields`).

``MPMSolver.build`` allocates the fields and fills both once; the operator modules (``p2g.py``,
``grid_update.py``, ``g2p.py``, ``outputs.py``, composed by ``kernels.py``) take them explicitly, never
the solver, so an operator can be built and tested alone from a hand-made bundle
(tests/unit/test_mpm_operators.py).

Besides the bundle, a builder receives the pluggable pieces it calls, each documented where it lives:
the constitutive laws (``laws.py``: the registry and the dispatch to a particle's law), the grid boundary
(``boundary.py``), the FLIP transfer (``transfer.py``; ``None`` under APIC) and ``count``, a ``ti.func``
returning the particle loops' bound (the constant n, or the active count with emitters and sinks).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

CHUNK_STRIDE = 512  # Taichi's smallest CPU range-for task (see solver.py's module docstring)


@dataclass(frozen=True)
class MPMParams:
    """Compile-time constants of the MPM kernels (plain Python values; changing one recompiles).

    Grid layout: node I sits at ``origin + I dx``; ``grid_shape`` nodes per axis (the domain plus the wall
    band). P2G: ``T`` private grid copies when ``chunked`` (CPU), else one grid with atomic adds (T = 1).
    A grid node carries ``gdim`` channels: momentum (dim), mass, [fixed mass if ``has_fixed``],
    [FLIP's momentum without the stress impulse (dim)].
    """

    dim: int
    dtype: Any  # ti.f32 or ti.f64
    dx: float
    origin: tuple[float, ...]  # position of node 0 [m]
    domain_lo: tuple[float, ...]  # particles are clamped to [domain_lo, domain_hi] after advection
    domain_hi: tuple[float, ...]
    grid_shape: tuple[int, ...]
    T: int  # grid copies (chunks of particles) in P2G
    chunked: bool  # private copies without atomics (CPU) or one grid with atomic adds
    gdim: int  # channels per grid node
    has_fixed: bool  # some particles are fixed (pinned): a fixed-mass channel and zero velocity
    n_bodies: int  # entities (per-entity frame statistics)
    # first of ``dim`` channels holding the nodes' mass-weighted particle position (the material's
    # position for the frictional colliders' gap test, boundary.GridBoundary.gap_test); -1: none
    gap_ch: int = -1
    # the gap test's nodes also gather the particles' affine (APIC) momentum, in the dim channels after
    # gap_ch's: the contact acts on the material's velocity at its position (boundary.GridBoundary._node)
    gap_aff: bool = False
    # the grid work runs over a block list (blocks.py) instead of the particles' node box: the grid fields
    # are zeroed there, so P2G does not clear its copies
    block_list: bool = False

    @property
    def inv_dx(self) -> float:
        return 1.0 / self.dx


@dataclass
class MPMFields:
    """The Taichi fields of the MPM substep and its per-frame kernels (struct of arrays).

    Particles (shape n): ``x`` position, ``v`` velocity, ``C`` affine velocity (APIC) or velocity
    gradient, ``F`` the displacement gradient H = F - I (not F, see ``MPMSolver._upload``), ``mass``,
    ``vol`` (rest volume), ``mid`` material id; ``fixed`` (u8, None without fixed particles), ``pid`` the
    particle's identity (None without emitters/sinks: then slot p is particle p).
    Grid: ``grid`` (T, *grid_shape) vectors of ``gdim`` channels (the P2G copies), ``grid_v`` the updated
    node velocity, ``grid_m`` the node mass (None unless a coupling phase reads it).
    Node boxes: ``bbox`` (T, 2) the [lo, hi) node box of each chunk's particles, ``bbox_all`` (2) their
    union; ``chunk_start`` (T + 1) the first particle of each chunk.
    Run-time parameters: ``gravity`` (0-d vector), ``mat_mu``/``mat_lam``/``mat_law_id`` per material
    (Lame parameters and index of the material's law in the solver's law list).
    Per-frame statistics: ``body_offsets`` (n_bodies + 1) particle ranges, ``stat_speed``/``stat_bad`` per
    entity (largest speed, count of non-finite particles), ``stat_stiff`` (0-d) the largest stiffness
    factor of a hardening law.
    """

    x: Any
    v: Any
    C: Any
    F: Any
    mass: Any
    vol: Any
    mid: Any
    fixed: Any
    pid: Any
    grid: Any
    grid_v: Any
    grid_m: Any
    bbox: Any
    bbox_all: Any
    chunk_start: Any
    gravity: Any
    mat_mu: Any
    mat_lam: Any
    mat_law_id: Any
    body_offsets: Any
    stat_speed: Any
    stat_bad: Any
    stat_stiff: Any
    blocks: Any = None  # blocks.BlockFields when params.block_list
