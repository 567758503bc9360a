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

The per-element bytes start from the fields each solver allocates (listed at each constant in the family's
simcli/solvers/<family>/resources.py) and are
scaled by a host factor measured with `benchmarks/memory_estimates.py` (three sizes per family, about
10x apart; table in docs/PERFORMANCE.md, "Memory"), chosen so the estimate is at or above the measured
peak and within 20 % of it.
"""

from __future__ import annotations

from pathlib import Path

# Each family's estimate is its own Taichi-free plug-in, simcli/solvers/<family>/resources.py (its Part,
# baseline, output fields and the key to lower); this module only sums them and compares with the machine.
from simcli.scene.estimate import HUGE, MIB, Estimate, Part, particle_count, threads_for  # noqa: F401
from simcli.solvers.fem import resources as fem
from simcli.solvers.mpm import resources as mpm
from simcli.solvers.pbd import resources as pbd
from simcli.solvers.sf import resources as sf
from simcli.solvers.sph import resources as sph

# the families in the order their Parts are listed
FAMILIES = {"MPM": mpm, "SPH": sph, "FEM": fem, "PBD": pbd, "SF": sf}

# Peak RSS [bytes] of `simcli run` with a tiny scene of each family (4 frames, hdf5 + vtk): the Python
# interpreter with numpy, h5py, pydantic and meshio, Taichi's runtime and the LLVM compile of that
# family's kernels (PBD's many constraint kernels compile to the most). Measured on the machine of
# docs/PERFORMANCE.md ("Memory"), Taichi 1.7, and rounded up; each number lives in its family's module.
BASELINE = {
    "MPM": mpm.BASELINE,
    "SPH": sph.BASELINE,
    "FEM": fem.BASELINE,
    "PBD": pbd.BASELINE,
    "PBF": pbd.BASELINE_LIQUID,  # PBD with a PBD.Liquid entity: the position-based fluid's kernels
    "SF": sf.BASELINE,
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


def estimate_memory(scene, scene_dir: Path | None = None) -> Estimate:
    """Peak resident memory [bytes] of `simcli run` on this scene, per family. Taichi-free; allocates
    nothing in proportion to the scene's particles, vertices or cells."""
    dim = scene.sim.dim
    lo, hi = scene.domain.bounds(dim)
    fams = [f for f in FAMILIES if f in scene.families]
    base = max((FAMILIES[f].baseline(scene) for f in fams), default=mpm.BASELINE)
    base += EXTRA_FAMILY * max(0, len(fams) - 1)
    est = Estimate(baseline=base, checkpoints=bool(scene.checkpoint.every))
    for f in fams:
        try:
            p = FAMILIES[f].estimate(scene, scene_dir, lo, hi)
        except (OverflowError, ZeroDivisionError):  # sizes beyond any machine (a spacing of 1e-300 m)
            p = Part(f, "beyond any machine", HUGE, *FAMILIES[f].FALLBACK)
        if p is not None:
            est.parts.append(p)
    return est


def estimate_disk(scene, est: Estimate) -> int:
    """Bytes the run writes: frames x bytes per frame for each output format (sim.h5, and VTK, whose zlib
    compression only makes it smaller), plus the static topology; checkpoints (the latest
    checkpoint.keep states) are counted as state copies of the estimate's solver share."""
    frames = scene.sim.n_steps // scene.output.every + 1
    per_frame = sum(p.out_bytes for p in est.parts)
    # reusing emitters also write each slot's emission number (int64) and birth time (float64) every frame
    per_frame += sum(16 * (em.max_particles + 1) for em in getattr(scene, "emitters", []) if em.reuse)
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
        f"{est.baseline / 2**20:.0f} MiB of it Python and Taichi) but only {avail / 2**30:.2f} GiB is "
        "available "
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
    keys = (
        "raise output.every, shorten sim.duration (or sim.steps), drop a format from output.formats or "
        "write fewer output.fields"
    )
    if need > DISK_FRACTION * free:
        return True, f"output.every: {what}; {keys}, or choose another folder with -o"
    return False, f"{what}: more than {DISK_WARN_FRACTION:.0%} of the free space"
