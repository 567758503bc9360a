"""The pieces every family's memory estimate is made of (no Taichi, no family imported): a family's
share (:class:`Part`), the whole estimate (:class:`Estimate`), particle counts from a morph alone and the
output floats per element. Each family's ``simcli/solvers/<family>/resources.py`` builds its Part from
these; ``simcli.scene.resources`` sums them. A leaf: it imports no family and no other estimate module.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

MIB = 1 << 20


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


HUGE = 10**18  # a count beyond any machine: the estimate says "too large" without overflowing


def cnt(x: float) -> int:
    """A count from a float, capped at HUGE (inf and nan included)."""
    return int(min(x, HUGE)) if math.isfinite(x) else HUGE


def particle_count(morph, spacing: float, dim: int, scene_dir=None) -> int:
    """Particles a morph gets at this spacing, in Python numbers (no int64 overflow at absurd spacings):
    a Box's lattice exactly, other shapes volume / spacing^dim (as sampling.estimate_particle_count)."""
    h = float(spacing)
    if morph.type == "Box":
        lo, hi = morph.bounds()
        n = 1
        for a, b in zip(lo, hi):
            k = (b - a) / h + 0.5
            n *= max(1, math.floor(k)) if math.isfinite(k) and k < HUGE else HUGE
        return min(n, HUGE)
    from simcli.geometry.sampling import morph_volume

    try:
        n = (morph_volume(morph, dim, scene_dir) ** (1.0 / dim) / h) ** dim
    except OverflowError:
        return HUGE
    return int(min(n, HUGE)) if math.isfinite(n) else HUGE


def fp_factor(scene) -> int:
    """2 at f64, 1 at f32: the factor on a field's bytes."""
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


VECTORS = {
    "position",
    "velocity",
    "displacement",
    "reaction",
    "vorticity",
    "force",
    "normal",
    "acceleration",
}


def out_floats(scene, default_fields: list[str], dim: int, with_position: bool = True) -> int:
    """Floats per element of one output frame: the family's default fields or output.fields (a
    particle or mesh family always writes its positions: with_position)."""
    f = scene.output.fields
    names = default_fields if f == "default" else list(f)
    if f != "default" and with_position and "position" not in names:
        names = ["position"] + names
    return sum(dim if n in VECTORS else 1 for n in names)
