"""The explicit inputs of the SPH kernel builders: what each operator module (density.py, non_pressure.py,
advect.py, wcsph.py, dfsph.py, wall_pressure.py, moving.py, outputs.py) may read, instead of the solver.

* ``SPHParams``: compile-time constants (Python values baked into the Taichi code: sizes, flags, option
  values). Frozen.
* ``SPHFields``: the Taichi fields of the particles, the boundary particles, the materials and the
  statistics. A field that the scene does not need is ``None`` (e.g. ``alpha`` with WCSPH).
* ``SPHFuncs``: the Taichi funcs the passes share, filled in build order by ``SPHSolver.build`` (or by a
  test): the active count and the cell sort first, then the smoothing kernels and the stencil
  (stencil.py), then the passes themselves.

``SPHSolver.build`` allocates the fields, makes one of each and calls the builders; a unit test can make
them by hand for a handful of particles (tests/unit/test_sph_operators.py). Taichi-free.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class SPHParams:
    """Compile-time constants of the SPH kernels."""

    dim: int
    f: Any  # the Taichi float type (ti.f32 or ti.f64)
    n: int  # particle slots (the active count may be lower: emitters, sinks)
    ps: float  # particle_size [m]
    h: float  # support radius [m]
    K: int  # neighbour-list capacity per particle
    R: int  # cells per support radius (CellGrid.R): the stencil is 2 R + 1 cells wide
    grid_dims: tuple[int, ...]  # the cell grid (CellGrid.dims)
    domain_lo: tuple[float, ...]
    domain_hi: tuple[float, ...]
    nbp: int  # boundary particles (0: none; their fields hold one slot then)
    uniform: bool  # one material: the pair terms in their single-material form, mass and volume constant
    m_c: float  # mass of a particle of the first material, rho0 V_rest [kg]
    V_c: float  # rest volume of a particle, V_rest [m^dim]
    pressure_solver: str  # "WCSPH" or "DFSPH"
    store_grad: bool  # the neighbour list keeps grad W_ij (DFSPH)
    has_viscosity: bool
    has_tension: bool
    has_noslip: bool  # no-slip boundary particles in reach and a viscous liquid
    shifting: float  # particle shifting coefficient (0: off)
    viscosity_operator: str  # "monaghan" or "morris"
    kgc: bool  # kernel gradient correction (DFSPH)
    kgc_scalar: bool  # ... its isotropic part only (gradient_correction: scalar)
    ext_walls: bool  # wall_pressure: extrapolated (wall_pressure.py)
    moving_boundary: bool  # a moving collider with boundary particles (moving.py)
    named_loads: bool  # a named collider with boundary particles: its loads are summed (moving.py)
    clamp_pressure: bool
    background_pressure: float  # WCSPH
    wall_pressure_relaxation: float  # WCSPH's extrapolated wall pressure: tau [s]
    warm_start: bool  # DFSPH
    divergence_solve: bool  # DFSPH
    max_divergence_error_percent: float  # DFSPH, host side
    max_density_error_percent: float
    max_divergence_iterations: int
    max_density_iterations: int
    cpu: bool  # a CPU backend (the counting sort's serial count)
    wall_standoff: float = 0.0  # the position guard's distance from the domain walls [m] (solvers.sph)
    volume_map: bool = False  # walls and static colliders as precomputed maps (volume_map.py), nbp = 0
    # WCSPH, delta-SPH (delta_sph.py): the density from the continuity equation, its diffusion, Monaghan's
    # artificial viscosity
    continuity: bool = False
    diffusion_model: str = ""  # "" (off), "molteni_colagrossi", "antuono" or "fourtakis"
    diffusion_delta: float = 0.0
    artificial_viscosity: float = 0.0
    # WCSPH, one material whose Tait exponent is a whole number (7 for water): the exponent, so that the
    # equation of state takes (rho / rho0)^n by multiplications instead of pow (wcsph.py); 0: pow
    int_exponent: int = 0

    @property
    def h2(self) -> float:
        return self.h * self.h

    @property
    def dfsph(self) -> bool:
        return self.pressure_solver == "DFSPH"

    @property
    def has_boundary(self) -> bool:
        return self.nbp > 0


@dataclass
class SPHFields:
    """The Taichi fields the SPH passes read and write. Particles are in cell order (``pid``: their entity
    order); per-particle fields have n slots, boundary fields max(1, nbp)."""

    # particles
    x: Any
    v: Any
    vnew: Any  # the velocity at the substep's end (WCSPH), scratch (DFSPH)
    mass: Any
    rho: Any
    p: Any
    mid: Any  # material index
    pid: Any  # entity-order index
    B: Any  # sum_b V_b grad W_ib
    Sb: Any  # sum_b V_b v_b . grad W_ib (DFSPH's density rate from the walls)
    nb_cnt: Any  # liquid neighbours listed
    nbb_cnt: Any  # boundary neighbours counted
    nb_j: Any  # neighbour list (n, K); extrapolated walls: boundary neighbours from nb_cnt to nbw_end
    # DFSPH: per list entry the kernel gradient's factor s, grad W_ij = (x_i - x_j) s (boundary entries: V_b
    # grad W_ib = V_b (x_i - x_b) s), 4 bytes instead of the vector's 12; else None
    nb_s: Any
    nrm: Any  # surface normals (surface tension)
    Mv: Any  # no-slip walls' viscous matrix and vector
    mw: Any
    shift: Any  # particle shifting displacement
    alpha: Any  # DFSPH factor
    nbw_end: Any  # extrapolated walls: end of the boundary part of the list
    bflag: Any  # extrapolated walls: boundary particle in reach of the liquid
    Lm: Any  # gradient correction, matrix
    Lc: Any  # gradient correction, scalar
    kk: Any  # DFSPH: stiffness increment of the iteration
    kacc: Any  # DFSPH: the solve's total stiffness
    kappa: Any  # DFSPH: warm starts of the density and divergence solves
    kappav: Any
    err_acc: Any  # DFSPH: the iteration's error sum, fixed point
    overflow: Any  # neighbour-list overflow count
    start: Any  # first particle of each cell (ncells + 1)
    # boundary particles, in cell order
    bx: Any
    bV: Any
    bvel: Any
    bns: Any  # no-slip flag
    bstart: Any
    bnear: Any  # a boundary particle lies in the cell's stencil
    bx0: Any  # body-frame position (colliders driven through ColliderPoses), else None
    bcol: Any  # collider index, -1: domain walls
    # materials and run-time parameters
    mat_rho0: Any
    mat_k: Any
    mat_n: Any
    mat_nu: Any
    mat_gamma: Any
    gravity: Any
    # statistics
    body_offsets: Any
    stat_speed: Any
    stat_bad: Any
    stat_dt: Any
    Hb: Any = None  # volume maps, extrapolated wall pressure: the walls' hydrostatic term per particle
    pw: Any = None  # volume maps, WCSPH's extrapolated wall pressure: each particle's relaxing wall pressure
    drho: Any = None  # WCSPH, density: continuity: d rho / dt of the substep (delta_sph.py)
    grad_rho: Any = None  # ... density_diffusion antuono: the renormalised density gradient
    pr2: Any = None  # WCSPH, one material: p_i / rho_i^2, written with the pressure (the force pass's pairs)
    m_rho: Any = None  # WCSPH, one material: m_i / rho_i, written with the pressure (the viscosity's pairs)
    bsrc: Any = None  # per boundary particle, a deformable body's sample index (deformable.py), -1: none


@dataclass
class SPHFuncs:
    """Taichi funcs shared by the passes, filled in build order."""

    count: Any = None  # the particle loops' bound: the active count or the constant n
    sort: Any = None  # the liquid's counting sort into cells (neighbours.py)
    cell_coords: Any = None
    linear: Any = None
    pushout: Any = None  # the advection's collider guard (boundary.make_pushout)
    # smoothing kernels (kernels.make_kernels)
    Wk: Any = None
    gradW: Any = None
    Ckern: Any = None
    W_gradW: Any = None
    # stencil.py
    rows: Any = None
    row_cell: Any = None
    mass_of: Any = None
    volume_of: Any = None
    # the passes
    neighbours_density: Any = None  # density.py
    non_pressure: Any = None  # non_pressure.py
    advect: Any = None  # advect.py
    wall_pressure: Any = None  # wall_pressure.py (a namespace), or None: Akinci's term alone
    move_boundary: Any = None  # moving.py
    load_pressure: Any = None  # moving.py
    load_viscous: Any = None
    boundary_map: Any = None  # volume_map.py: boundary(x) -> the walls' and static colliders' sums
    map_wall_k: Any = None  # volume_map.py: DFSPH's boundary stiffness next to a particle (Shepard average)
