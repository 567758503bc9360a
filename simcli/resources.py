"""Memory and disk a scene will need, estimated from the scene alone: no Taichi, no sampling, no mesh built.

Counts come from the morphs analytically (a Box's lattice exactly, other shapes from their volume over
particle_size^3, a cloth Rectangle from its resolution, FEM and PBD soft bodies from the FEM mesher's own
count, an SF grid from solvers.sf.resolution); a mesh file is read to get its volume or triangle count,
which costs memory proportional to the file, never to the particle count. A 8000 x 8000 cloth is
refused in milliseconds.

Peak resident memory of `simcli run` =

    baseline of the heaviest family present                  (Python, numpy, h5py, the Taichi runtime
                                                              and the LLVM compile of the family's
                                                              kernels: measured with a tiny scene)
  + sum over families of  per-element bytes x elements       (the solver's Taichi fields, the numpy
                                                              arrays the set-up builds and keeps, the
                                                              frame's output copies and the h5py/VTK
                                                              write buffers)

The per-element bytes start from the fields each solver allocates (listed at each constant) and are
scaled by a host factor measured with `benchmarks/memory_estimates.py` (three sizes per family, about
10x apart; table in docs/PERFORMANCE.md, "Memory"), chosen so the estimate is at or above the measured
peak and within 20 % of it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

MIB = 1 << 20

# Peak RSS [bytes] of `simcli run` with a tiny scene of each family (4 frames, hdf5 + vtk): the Python
# interpreter with numpy, h5py, pydantic and meshio, Taichi's runtime and the LLVM compile of that
# family's kernels (PBD's many constraint kernels compile to the most). Measured on the machine of
# docs/PERFORMANCE.md ("Memory"), Taichi 1.7, and rounded up.
BASELINE = {
    "MPM": 222 * MIB,
    "SPH": 210 * MIB,
    "FEM": 190 * MIB,
    "PBD": 360 * MIB,
    "PBF": 530 * MIB,  # PBD with a PBD.Liquid entity: the position-based fluid's kernels
    "SF": 320 * MIB,
}
# a second and third family in the same process: their kernels compile one after the other, so the compile
# peak is the largest family's, not the sum; each adds its imports and runtime state (measured: MPM + FEM
# peaked at 314 MB where MPM's baseline is 222 and the two families' elements about 118)
EXTRA_FAMILY = 16 * MIB

# Refuse a scene whose estimate exceeds this share of the memory available now (psutil's 'available':
# free memory plus what the kernel can reclaim). The estimate is itself at or above the measured peak;
# the 10 % left over is for other processes' growth while the run starts.
MEMORY_FRACTION = 0.9
# Refuse a scene whose estimated output exceeds this share of the free space of its output folder.
DISK_FRACTION = 0.95


@dataclass
class Part:
    """One family's share: what it holds, its bytes, and the scene key that makes it smaller."""

    family: str
    what: str  # "1,234,567 particles, 2,345,678 grid nodes"
    bytes: int
    key: tuple  # scene path of the key to change, e.g. ("solvers", "mpm", "grid_density")
    advice: str  # "lower solvers.mpm.grid_density (or raise solvers.mpm.particle_size)"
    out_bytes: int = 0  # bytes per output frame, one format
    static_out_bytes: int = 0  # written once (cells, topology)
    state_bytes: int = 0  # the numpy copy of the solver state a checkpoint writes


@dataclass
class Estimate:
    baseline: int
    parts: list[Part] = field(default_factory=list)
    checkpoints: bool = False  # checkpoint.every > 0: the state copies count in the peak

    @property
    def total(self) -> int:
        ckpt = sum(p.state_bytes for p in self.parts) if self.checkpoints else 0
        return self.baseline + sum(p.bytes for p in self.parts) + ckpt

    def largest(self) -> Part | None:
        return max(self.parts, key=lambda p: p.bytes, default=None)

    def elements_text(self) -> str:
        return "; ".join(f"{p.family}: {p.what}" for p in self.parts)


# --------------------------------------------------------------------------------------- per element

_HUGE = 10**18  # a count beyond any machine: the estimate says "too large" without overflowing


def _cnt(x: float) -> int:
    """A count from a float, capped at _HUGE (inf and nan included)."""
    return int(min(x, _HUGE)) if math.isfinite(x) else _HUGE


def particle_count(morph, spacing: float, dim: int, scene_dir=None) -> int:
    """Particles a morph gets at this spacing, in Python numbers (no int64 overflow at absurd spacings):
    a Box's lattice exactly, other shapes volume / spacing^dim (as sampling.estimate_particle_count)."""
    h = float(spacing)
    if morph.type == "Box":
        lo, hi = morph.bounds()
        n = 1
        for a, b in zip(lo, hi):
            k = (b - a) / h + 0.5
            n *= max(1, math.floor(k)) if math.isfinite(k) and k < _HUGE else _HUGE
        return min(n, _HUGE)
    from simcli.geometry.sampling import morph_volume

    try:
        n = (morph_volume(morph, dim, scene_dir) ** (1.0 / dim) / h) ** dim
    except OverflowError:
        return _HUGE
    return int(min(n, _HUGE)) if math.isfinite(n) else _HUGE


def _fp(scene) -> int:
    return 2 if scene.sim.precision == "f64" else 1


def threads_for(scene) -> int:
    """The CPU threads the run will use (as simcli.backend picks them)."""
    if scene.sim.threads is not None:
        return int(scene.sim.threads)
    env = os.environ.get("SLURM_CPUS_PER_TASK") or os.environ.get("SIMCLI_THREADS")
    if env and env.isdigit():
        return int(env)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


# MPM, per particle at f32: x, v (dim), C, F (dim^2), mass, volume, material id, fixed flag; the laws'
# state (plastic J, a warm-start rotation: up to 5); the five derived output fields (J, stress, pressure,
# Jp, energy) once written. Host: the sampled bodies (x, v f64, volume, mass f64, fixed), the upload's
# f32 copies, each frame's output copies. Host factor measured.
def _mpm_particle_bytes(dim: int, fp: int) -> int:
    device = 4 * fp * (2 * dim + 2 * dim * dim + 2 + 5 + 5) + 4 + 1
    host = 8 * (2 * dim + 2) + 1 + 4 * fp * (2 * dim + dim * dim)
    return device + host


MPM_HOST_FACTOR = 1.05
# per grid node: T private copies of (momentum dim, mass, fixed mass) when they fit in 1 GiB, the new
# velocity (dim) and the boundary's per-node flags
MPM_PRIVATE_GRID_BYTES = 1 << 30


def _mpm(scene, scene_dir, lo, hi) -> Part | None:
    dim = scene.sim.dim
    mpm = scene.solvers.mpm
    fp = _fp(scene)
    n = sum(particle_count(e.morph, mpm.spacing, dim, scene_dir) for e in scene.entities if e.family == "MPM")
    nodes = math.prod(
        _cnt(math.ceil(min((hi[a] - lo[a]) * mpm.grid_density, 1e30) - 1e-6)) + 7 for a in range(dim)
    )
    gdim = dim + 2
    copy = nodes * gdim * 4 * fp
    t = threads_for(scene)
    copies = t if t * copy <= MPM_PRIVATE_GRID_BYTES and scene.sim.backend in ("cpu", "auto") else 1
    grid = copies * copy + nodes * (dim * 4 * fp + 4)
    b = int(n * _mpm_particle_bytes(dim, fp) * MPM_HOST_FACTOR) + grid
    return Part(
        "MPM",
        f"{n:,} particles, {nodes:,} grid nodes x {copies} copies",
        b,
        ("solvers", "mpm", "grid_density"),
        "lower solvers.mpm.grid_density (or raise solvers.mpm.particle_size), or shrink the domain",
        out_bytes=n * _out_floats(scene, "MPM", dim) * 4,  # output is float32 at either precision
        # x, v, C, H (the solver's precision), F in float64, the laws' state (Jp, ...): measured 447 MB at
        # 2.6 M particles (3D, f32), 176 B each by this count
        state_bytes=n * (4 * fp * (2 * dim + 2 * dim * dim + 2) + 8 * dim * dim),
    )


# SPH, per particle at f32: x, v, new v, boundary gradient sum (dim each), 10 scalars, 6 ints, the reorder
# copies (2 dim + 4) and the neighbour list (capacity x (index + gradient for DFSPH)); per boundary
# particle position, velocity, volume, flag; per cell (cell = support / 2) count and start offsets of the
# liquid and of the boundary particles. Host: the sampled bodies and the output copies.
def _sph_bytes_per_particle(dim: int, support_factor: float, dfsph: bool = True, kgc: bool = False) -> int:
    from simcli.solvers.sph.neighbours import neighbour_capacity  # numpy only, no Taichi

    entry = 1 + dim if dfsph else 1
    correction = dim * dim if kgc else 0
    return 4 * (4 * dim + 10 + 6 + 2 * dim + 4 + correction + neighbour_capacity(dim, support_factor) * entry)


SPH_HOST_PER_PARTICLE = 8 * 8  # sampled x, v (f64), mass, volume; output copies
SPH_HOST_FACTOR = 1.15


def _sph(scene, scene_dir, lo, hi) -> Part | None:
    from simcli.solvers.sph.neighbours import neighbour_capacity

    dim = scene.sim.dim
    sph = scene.solvers.sph
    fp = _fp(scene)
    n = sum(
        particle_count(e.morph, sph.particle_size, dim, scene_dir)
        for e in scene.entities
        if e.family == "SPH"
    )
    ext = [hi[a] - lo[a] for a in range(dim)]
    faces = sum(math.prod(ext[b] for b in range(dim) if b != a) for a in range(dim))
    layers = max(2, math.ceil(sph.support_factor - 1e-9))
    h = float(sph.particle_size)
    n_bnd = _cnt(2 * layers * (faces ** (1.0 / (dim - 1)) / h) ** (dim - 1))
    cell = 0.5 * sph.support_factor * h
    cells = math.prod(_cnt(math.ceil(min(e / cell, 1e30))) + 6 for e in ext)
    per_p = _sph_bytes_per_particle(
        dim, sph.support_factor, sph.pressure_solver == "DFSPH", sph.gradient_correction
    )
    per_b = 4 * (2 * dim + 2)
    if sph.wall_model == "extrapolated":  # wall_pressure.py: 4 scalars and a list of (index, weight)
        per_b += 4 * (4 + 2 * max(8, neighbour_capacity(dim, sph.support_factor) // 2))
        per_p += 4
    device = (n * per_p + n_bnd * per_b + cells * 4 * 3) * fp
    b = int((device + n * SPH_HOST_PER_PARTICLE) * SPH_HOST_FACTOR)
    return Part(
        "SPH",
        f"{n:,} particles, {n_bnd:,} boundary particles, {cells:,} neighbour-grid cells",
        b,
        ("solvers", "sph", "particle_size"),
        "raise solvers.sph.particle_size, or shrink the domain",
        out_bytes=n * _out_floats(scene, "SPH", dim) * 4,  # output is float32 at either precision
        state_bytes=n * 4 * fp * (2 * dim + 4),  # x, v, density, pressure and the solver's scalars
    )


FEM_HOST_FACTOR = 1.17


def _fem(scene, scene_dir, lo, hi) -> Part | None:
    from simcli.solvers.fem.mesh import estimate_bytes, estimate_counts

    nv = nt = 0
    for e in scene.entities:
        if e.family == "FEM":
            v, t = estimate_counts(e, scene.solvers.fem, scene_dir)
            nv, nt = nv + v, nt + t
    b = int(estimate_bytes(nv, nt, scene.solvers.fem.integrator, scene.sim.precision) * FEM_HOST_FACTOR)
    return Part(
        "FEM",
        f"{nv:,} vertices, {nt:,} tetrahedra",
        b,
        ("solvers", "fem", "resolution"),
        "lower solvers.fem.resolution (Box morphs) or raise solvers.fem.max_volume (other shapes)",
        out_bytes=nv * _out_floats(scene, "FEM", 3) * 4,  # float32 at either precision
        state_bytes=nv * 4 * _fp(scene) * 6,  # x, v
        static_out_bytes=nt * 4 * 8,
    )


# PBD, per vertex at f32: x, v, previous x, rest x, reaction, fixed velocity (3 each), inverse mass,
# radius, drag, body id, two frictions, the contact's position delta (3) and the hash grid's slots (about
# 2 per vertex: count, start, cursor, sorted); per constraint: indices (2 or 4), rest value, compliance,
# lambda, its colour. Host: the mesh (x, mass f64), constraints as int64 pairs and quads, the colouring's
# work arrays. PBD.Liquid adds the neighbour list (64 int32) and 8 scalars per particle.
PBD_VERTEX_BYTES = 4 * (18 + 6 + 3 + 8) + 8 * (3 + 1 + 3)
PBD_CONSTRAINT_BYTES = 4 * (4 + 3 + 1) + 8 * (4 + 1) * 2
PBD_LIQUID_BYTES = 4 * (64 + 1 + 8 + 3)
PBD_HOST_FACTOR = 1.7  # meshes: vertices and constraints
PBD_PARTICLE_HOST_FACTOR = 1.24  # free particles (PBD.Particle, PBD.Liquid)


def pbd_entity_counts(e, opts, scene_dir=None) -> tuple[int, int, str]:
    """(vertices, constraints, kind) of a PBD entity, from its morph alone (no mesh built). Mesh files are
    read (memory proportional to the file); every other morph is counted analytically."""
    m = e.morph
    mat = e.material.type
    if mat in ("PBD.Particle", "PBD.Liquid"):
        n = particle_count(m, opts.particle_size, 3, scene_dir)
        return n, 0, "particles"
    if mat == "PBD.Elastic" and m.type != "Line":
        from simcli.solvers.fem.config import FEMOptions
        from simcli.solvers.fem.mesh import estimate_counts

        nv, nt = estimate_counts(e, FEMOptions(resolution=opts.tet_resolution), scene_dir)
        # a Box's 6-tet cells have 7 edges per cell (about 7 / 6 per tet); TetGen's meshes about 1.2
        return nv, nt + int(1.2 * nt), "tets"
    if m.type == "Rectangle":
        nu, nv = ([m.resolution] * 2) if isinstance(m.resolution, int) else list(m.resolution)
        edges = 3 * nu * nv + nu + nv
        quads = 3 * nu * nv - nu - nv
        return (nu + 1) * (nv + 1), edges + quads, "triangles"
    if m.type == "Mesh":  # an open surface: vertices and triangles from the file
        from simcli.solvers.pbd.topology import read_open_surface

        x, tris = read_open_surface(m, scene_dir)
        return len(x), 3 * len(tris), "triangles"
    if m.type == "Line":
        n = (m.segments + 1) if m.segments is not None else len(m.points)
        return n, 2 * n, "lines"
    return 0, 0, "?"


def _pbd(scene, scene_dir, lo, hi) -> Part | None:
    opts = scene.solvers.pbd
    fp = _fp(scene)
    nv = nc = n_liq = n_free = 0
    big, big_n = None, -1
    for i, e in enumerate(scene.entities):
        if e.family != "PBD":
            continue
        v, c, kind = pbd_entity_counts(e, opts, scene_dir)
        nv, nc = nv + v, nc + c
        if kind == "particles":
            n_free += v
        if e.material.type == "PBD.Liquid":
            n_liq += v
        if v > big_n:
            big, big_n = (i, e, kind), v
    meshed = (nv - n_free) * PBD_VERTEX_BYTES * fp + nc * PBD_CONSTRAINT_BYTES
    free = n_free * PBD_VERTEX_BYTES * fp + n_liq * PBD_LIQUID_BYTES * fp
    b = int(meshed * PBD_HOST_FACTOR + free * PBD_PARTICLE_HOST_FACTOR)

    i, e, kind = big
    if kind == "particles":
        key, advice = ("solvers", "pbd", "particle_size"), "raise solvers.pbd.particle_size"
    elif kind == "tets":
        key, advice = ("solvers", "pbd", "tet_resolution"), "lower solvers.pbd.tet_resolution"
    elif e.morph.type == "Rectangle":
        key = ("entities", i, "morph", "resolution")
        advice = f"lower entities.{i}.morph.resolution (entity '{e.name}')"
    elif e.morph.type == "Line":
        key = ("entities", i, "morph", "segments")
        advice = f"lower entities.{i}.morph.segments (entity '{e.name}')"
    else:
        key, advice = ("entities", i, "morph", "file"), f"use a coarser mesh for entity '{e.name}'"
    return Part(
        "PBD",
        f"{nv:,} vertices/particles, {nc:,} constraints",
        b,
        key,
        advice,
        out_bytes=nv * _out_floats(scene, "PBD", 3) * 4,  # output is float32 at either precision
        state_bytes=nv * 4 * fp * 6,  # x, v
    )


SF_HOST_FACTOR = 1.38


def _sf(scene, scene_dir, lo, hi) -> Part | None:
    from simcli.solvers.sf.config import estimate_bytes

    n, _ = scene.solvers.sf.cells(lo, hi)
    cells = math.prod(n)
    mat = next((e.material for e in scene.entities if e.family == "SF"), None)
    # estimate_bytes includes 256 MiB of Taichi runtime, counted here in the baseline
    b = int((estimate_bytes(scene.solvers.sf, mat, n, scene.sim.precision) - (256 << 20)) * SF_HOST_FACTOR)
    return Part(
        "SF",
        f"{'x'.join(map(str, n))} = {cells:,} grid cells",
        b,
        ("solvers", "sf", "resolution"),
        "lower solvers.sf.resolution",
        out_bytes=cells * _out_floats(scene, "SF", len(n)) * 4,  # float32 at either precision
        state_bytes=cells * 4 * _fp(scene) * (len(n) + 3),  # face velocities, smoke and temperature, pressure
    )


_KEYS = {
    "MPM": (
        ("solvers", "mpm", "grid_density"),
        "lower solvers.mpm.grid_density (or raise solvers.mpm.particle_size)",
    ),
    "SPH": (("solvers", "sph", "particle_size"), "raise solvers.sph.particle_size"),
    "FEM": (("solvers", "fem", "resolution"), "lower solvers.fem.resolution"),
    "PBD": (
        ("solvers", "pbd", "particle_size"),
        "raise solvers.pbd.particle_size or lower the morphs' resolution",
    ),
    "SF": (("solvers", "sf", "resolution"), "lower solvers.sf.resolution"),
}
_FAMILIES = {"MPM": _mpm, "SPH": _sph, "FEM": _fem, "PBD": _pbd, "SF": _sf}
_DEFAULT_FIELDS = {
    "MPM": ["position", "velocity"],
    "SPH": ["position", "velocity"],
    "FEM": ["position", "velocity", "displacement", "von_mises", "J"],
    "PBD": ["position", "velocity", "displacement"],
    "SF": ["velocity", "pressure", "density", "temperature", "divergence"],
}
_VECTORS = {
    "position",
    "velocity",
    "displacement",
    "reaction",
    "vorticity",
    "force",
    "normal",
    "acceleration",
}


def _out_floats(scene, family: str, dim: int) -> int:
    f = scene.output.fields
    names = _DEFAULT_FIELDS[family] if f == "default" else list(f)
    if f != "default" and family != "SF" and "position" not in names:
        names = ["position"] + names
    return sum(dim if n in _VECTORS else 1 for n in names)


def estimate_memory(scene, scene_dir: Path | None = None) -> Estimate:
    """Peak resident memory [bytes] of `simcli run` on this scene, per family. Taichi-free; allocates
    nothing in proportion to the scene's particles, vertices or cells."""
    dim = scene.sim.dim
    lo, hi = scene.domain.bounds(dim)
    fams = [f for f in _FAMILIES if f in scene.families]
    liquid = any(e.material.type == "PBD.Liquid" for e in scene.entities)
    keys = ["PBF" if f == "PBD" and liquid else f for f in fams]
    base = max((BASELINE[k] for k in keys), default=BASELINE["MPM"]) + EXTRA_FAMILY * max(0, len(fams) - 1)
    est = Estimate(baseline=base, checkpoints=bool(scene.checkpoint.every))
    for f in fams:
        try:
            p = _FAMILIES[f](scene, scene_dir, lo, hi)
        except (OverflowError, ZeroDivisionError):  # sizes beyond any machine (a spacing of 1e-300 m)
            p = Part(f, "beyond any machine", _HUGE, *_KEYS[f])
        if p is not None:
            est.parts.append(p)
    return est


def estimate_disk(scene, est: Estimate) -> int:
    """Bytes the run writes: frames x bytes per frame for each output format (sim.h5, and VTK, whose zlib
    compression only makes it smaller), plus the static topology; checkpoints (the latest
    checkpoint.keep states) are counted as state copies of the estimate's solver share."""
    frames = scene.sim.n_steps // scene.output.every + 1
    per_frame = sum(p.out_bytes for p in est.parts)
    static = sum(p.static_out_bytes for p in est.parts)
    nfmt = len(set(scene.output.formats))
    ckpt = 0
    if scene.checkpoint.every:
        ckpt = max(1, scene.checkpoint.keep) * sum(p.state_bytes for p in est.parts)
    # fixed costs: run.json, scene.yaml, .xdmf/.pvd, HDF5 metadata and VTK headers (about 4 KiB per frame
    # and entity and format)
    n_ent = max(1, len(scene.entities))
    overhead = 64 * 1024 + nfmt * frames * n_ent * 4096
    return int(nfmt * (frames * per_frame + static) + ckpt + overhead)


# ------------------------------------------------------------------------------------- the machine


def available_memory() -> int:
    try:
        import psutil

        return int(psutil.virtual_memory().available)
    except Exception:  # pragma: no cover - psutil missing
        try:
            with open("/proc/meminfo") as f:
                for line in f:
                    if line.startswith("MemAvailable:"):
                        return int(line.split()[1]) * 1024
        except OSError:
            pass
    return 1 << 62


def free_disk(path: Path) -> int:
    """Free bytes on the file system that holds path (or its nearest existing parent)."""
    import shutil

    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return int(shutil.disk_usage(p).free)
    except OSError:
        return 1 << 62


def memory_problem(est: Estimate, avail: int | None = None) -> tuple[tuple, str] | None:
    """(scene key, message) when the estimate exceeds MEMORY_FRACTION of the available memory."""
    avail = available_memory() if avail is None else avail
    if est.total <= MEMORY_FRACTION * avail:
        return None
    big = est.largest()
    key = big.key if big is not None else ("entities",)
    advice = big.advice if big is not None else "make the scene smaller"
    return key, (
        f"scene too large: needs about {est.total / 2**30:.2f} GiB ({est.elements_text()}; "
        f"{est.baseline / 2**20:.0f} MiB of it Python and Taichi) but only {avail / 2**30:.2f} GiB is available "
        f"(limit {MEMORY_FRACTION:.0%} of it); {advice}"
    )


DISK_WARN_FRACTION = 0.5  # warn when the output would take more than this share of the free space


def disk_problem(scene, scene_dir, out: Path, frames_done: int = 0) -> tuple[bool, str] | None:
    """(fatal, message) when the estimated output does not fit (fatal: over DISK_FRACTION of the free
    space of the output folder's file system) or takes most of it (a warning: over DISK_WARN_FRACTION).
    frames_done: frames a resumed run has written already."""
    est = estimate_memory(scene, scene_dir)
    need = estimate_disk(scene, est)
    frames = scene.sim.n_steps // scene.output.every + 1
    if frames_done:
        need = int(need * max(0, frames - frames_done) / frames)
    free = free_disk(out)
    if need <= DISK_WARN_FRACTION * free:
        return None
    what = (
        f"the output needs about {need / 2**30:.2f} GiB ({frames:,} frames of {est.elements_text()}, "
        f"formats {', '.join(scene.output.formats)}) and {out} has {free / 2**30:.2f} GiB free"
    )
    keys = "raise output.every, shorten sim.duration (or sim.steps), drop a format from output.formats or write fewer output.fields"
    if need > DISK_FRACTION * free:
        return True, f"output.every: {what}; {keys}, or choose another folder with -o"
    return False, f"{what}: more than {DISK_WARN_FRACTION:.0%} of the free space"
