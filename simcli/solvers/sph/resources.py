"""SPH's memory estimate from the scene alone (no Taichi): its Part of ``simcli.scene.resources``, and
the neighbour-list capacity the solver allocates (numpy only, so the estimate needs no Taichi module)."""

from __future__ import annotations

import math

from simcli.scene.estimate import MIB, Part, cnt, fp_factor, out_floats, particle_count

# Peak RSS of `simcli run` with a tiny SPH scene (simcli.scene.resources: the baseline)
BASELINE = 210 * MIB
FALLBACK = (("solvers", "sph", "particle_size"), "raise solvers.sph.particle_size")
DEFAULT_FIELDS = ["position", "velocity"]


def baseline(scene) -> int:
    return BASELINE


def neighbour_capacity(dim: int, support_factor: float) -> int:
    """Neighbour-list slots per particle: twice the neighbours of a liquid at rest density (pi f^2 in 2D,
    4/3 pi f^3 in 3D for a support of f particle sizes), rounded up to a multiple of 8: 32 and 72 at f = 2."""
    rest = math.pi * support_factor**2 if dim == 2 else 4.0 / 3.0 * math.pi * support_factor**3
    return int(8 * math.ceil(2.0 * rest / 8.0))


# SPH, per particle at f32: x, v, new v, boundary gradient sum (dim each), 10 scalars, 6 ints, the reorder
# copies (2 dim + 4) and the neighbour list (capacity x (index + the kernel-gradient factor: one number
# since 2026-11-27, grad W_ij = (x_i - x_j) s_ij, 8 bytes per entry instead of 16)); per boundary
# particle position, velocity, volume, flag; per cell (cell = support / 2) count and start offsets of the
# liquid and of the boundary particles. Host: the sampled bodies and the output copies.
def _sph_bytes_per_particle(
    dim: int, support_factor: float, dfsph: bool = True, kgc: bool | str = False
) -> int:
    # index + grad W's factor: DFSPH, and since 2026-11-27 WCSPH on the CPU too (a GPU's WCSPH list keeps the
    # index alone: the estimate counts the CPU's)
    entry = 2
    # DFSPH gradient_correction: a dim x dim matrix per particle, or one number (scalar, with k_i c_i beside
    # it); WCSPH: p / rho^2
    correction = 2 if kgc == "scalar" else dim * dim if kgc else 0
    if not dfsph:
        correction = 1
    return 4 * (4 * dim + 10 + 6 + 2 * dim + 4 + correction + neighbour_capacity(dim, support_factor) * entry)


SPH_HOST_PER_PARTICLE = 8 * 8  # sampled x, v (f64), mass, volume; output copies
SPH_HOST_FACTOR = 1.15


def estimate(scene, scene_dir, lo, hi) -> Part | None:
    dim = scene.sim.dim
    sph = scene.solvers.sph
    fp = fp_factor(scene)
    n = sum(
        particle_count(e.morph, sph.particle_size, dim, scene_dir)
        for e in scene.entities
        if e.family == "SPH"
    )
    # emitters' reserved slots (and their fresh row): allocated up front (simcli/solvers/sources.py)
    n += sum(em.max_particles + 1 for em in getattr(scene, "emitters", []) if em.family == "SPH")
    ext = [hi[a] - lo[a] for a in range(dim)]
    faces = sum(math.prod(ext[b] for b in range(dim) if b != a) for a in range(dim))
    layers = max(2, math.ceil(sph.support_factor - 1e-9))
    h = float(sph.particle_size)
    n_bnd = cnt(2 * layers * (faces ** (1.0 / (dim - 1)) / h) ** (dim - 1))
    cell = 0.5 * sph.support_factor * h
    cells = math.prod(cnt(math.ceil(min(e / cell, 1e30))) + 6 for e in ext)
    per_p = _sph_bytes_per_particle(
        dim, sph.support_factor, sph.pressure_solver == "DFSPH", sph.gradient_correction_mode
    )
    per_b = 4 * (2 * dim + 2)
    if sph.wall_model == "extrapolated":  # wall_pressure.py: 4 scalars (+ WCSPH's relaxing pressure), a list
        per_b += 4 * (5 + 2 * max(8, neighbour_capacity(dim, sph.support_factor) // 2))
        per_p += 4
    device = (n * per_p + n_bnd * per_b + cells * 4 * 3) * fp
    b = int((device + n * SPH_HOST_PER_PARTICLE) * SPH_HOST_FACTOR)
    return Part(
        "SPH",
        f"{n:,} particles, {n_bnd:,} boundary particles, {cells:,} neighbour-grid cells",
        b,
        ("solvers", "sph", "particle_size"),
        "raise solvers.sph.particle_size, or shrink the domain",
        out_bytes=n * out_floats(scene, DEFAULT_FIELDS, dim) * 4,  # output is float32 at either precision
        state_bytes=n * 4 * fp * (2 * dim + 4),  # x, v, density, pressure and the solver's scalars
    )
