"""MPM's memory estimate from the scene alone (no Taichi): its Part of ``simcli.scene.resources``."""

from __future__ import annotations

import math

from simcli.scene.estimate import MIB, Part, cnt, fp_factor, out_floats, particle_count, threads_for

# Peak RSS of `simcli run` with a tiny MPM scene (simcli.scene.resources: the baseline)
BASELINE = 222 * MIB
FALLBACK = (
    ("solvers", "mpm", "grid_density"),
    "lower solvers.mpm.grid_density (or raise solvers.mpm.particle_size)",
)
DEFAULT_FIELDS = ["position", "velocity"]


def baseline(scene) -> int:
    return BASELINE


# MPM, per particle at f32: x, v (dim), C, F (dim^2), mass, volume, material id, fixed flag; the laws'
# state (at least 5: the corotated law's quaternion, muscle fibres; the plastic laws' _plastic_floats);
# the five derived output fields (J, stress, pressure, Jp, energy) once written. Host: the sampled bodies
# (x, v f64, volume, mass f64, fixed), the upload's f32 copies, each frame's output copies. Host factor
# measured.
def _mpm_particle_bytes(dim: int, fp: int, law: int = 5) -> int:
    device = 4 * fp * (2 * dim + 2 * dim * dim + 2 + law + 5) + 4 + 1
    host = 8 * (2 * dim + 2) + 1 + 4 * fp * (2 * dim + dim * dim)
    return device + host


MPM_HOST_FACTOR = 1.05
# per grid node: T private copies of (momentum dim, mass, fixed mass) when they fit in 1 GiB, the new
# velocity (dim) and the boundary's per-node flags
MPM_PRIVATE_GRID_BYTES = 1 << 30


def _gap_test(c) -> bool:
    """A collider whose contact acts on a node only once its material reaches the surface: a frictional,
    static, unnamed slip or separate surface of an analytic shape (simcli/solvers/mpm/boundary.py,
    GridBoundary.gap_test), which adds dim channels to every grid node (2 dim under APIC)."""
    return (
        c.type != "Mesh"
        and c.boundary != "sticky"
        and float(c.friction or 0.0) > 0
        and getattr(c, "motion", None) is None
        and not getattr(c, "name", None)
    )


def _image(c) -> bool:
    """A collider or rigid body with an image whose fade reads the nodes' material position (a
    frictionless slip or separate surface of an analytic shape: GridBoundary.has_image), which adds dim
    channels to every grid node too."""
    return (
        getattr(c, "type", getattr(getattr(c, "morph", None), "type", "")) != "Mesh"
        and getattr(c, "boundary", "separate") != "sticky"
        and float(getattr(c, "friction", 0.0) or 0.0) <= 0
    )


def _plastic_floats(scene, dim: int) -> int:
    """Per-particle floats of the plastic MPM laws (plasticity.py), 0 without them: the Kirchhoff stress
    (dim^2), J_p and sand's volume correction, in 2D the out-of-plane strain, in 3D the warm-start
    quaternion of U (4)."""
    plastic = ("MPM.Sand", "MPM.Snow", "MPM.ElastoPlastic")
    bodies = [*scene.entities, *getattr(scene, "emitters", [])]  # an emitter-fed pour has no sand entity
    n_laws = len({b.material.type for b in bodies if b.family == "MPM" and b.material.type in plastic})
    # each plastic law allocates its state for the whole particle range
    return n_laws * (dim * dim + 2 + (4 if dim == 3 else 1))


def estimate(scene, scene_dir, lo, hi) -> Part | None:
    dim = scene.sim.dim
    mpm = scene.solvers.mpm
    fp = fp_factor(scene)
    n = sum(particle_count(e.morph, mpm.spacing, dim, scene_dir) for e in scene.entities if e.family == "MPM")
    # emitters' reserved slots (and their fresh row): allocated up front (simcli/solvers/sources.py)
    n += sum(em.max_particles + 1 for em in getattr(scene, "emitters", []) if em.family == "MPM")
    nodes = math.prod(
        cnt(math.ceil(min((hi[a] - lo[a]) * mpm.grid_density, 1e30) - 1e-6)) + 7 for a in range(dim)
    )
    gdim = dim + 2
    bodies = list(scene.colliders) + list(getattr(scene, "rigid_bodies", None) or [])
    gap_test = any(_gap_test(c) for c in scene.colliders)
    if gap_test or any(_image(c) for c in bodies):  # the nodes' material position
        gdim += dim
        if gap_test and getattr(mpm, "transfer", "apic") != "flip":  # and their affine momentum (APIC)
            gdim += dim
    copy = nodes * gdim * 4 * fp
    t = threads_for(scene)
    copies = t if t * copy <= MPM_PRIVATE_GRID_BYTES and scene.sim.backend in ("cpu", "auto") else 1
    grid = copies * copy + nodes * (dim * 4 * fp + 4)
    plastic = _plastic_floats(scene, dim)
    b = int(n * _mpm_particle_bytes(dim, fp, max(5, plastic)) * MPM_HOST_FACTOR) + grid
    return Part(
        "MPM",
        f"{n:,} particles, {nodes:,} grid nodes x {copies} copies",
        b,
        ("solvers", "mpm", "grid_density"),
        "lower solvers.mpm.grid_density (or raise solvers.mpm.particle_size), or shrink the domain",
        out_bytes=n * out_floats(scene, DEFAULT_FIELDS, dim) * 4,  # output is float32 at either precision
        # x, v, C, H (the solver's precision), F in float64, the laws' state (Jp, ...): measured 447 MB at
        # 2.6 M particles (3D, f32), 176 B each by this count (a liquid); the plastic laws' state on top
        state_bytes=n * (4 * fp * (2 * dim + 2 * dim * dim + 2 + plastic) + 8 * dim * dim),
    )
