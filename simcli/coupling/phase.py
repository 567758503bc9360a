"""The coupling phase: which pairs are coupled, their build, and the substep in three phases."""

from __future__ import annotations

import time
from typing import Any, Callable

# the scene's coupling keys, as (key, family a, family b) in the order the coupling phase runs them
PAIRS = (
    ("mpm_sph", "mpm", "sph"),
    ("mpm_pbd", "mpm", "pbd"),
    ("mpm_fem", "mpm", "fem"),
    ("sph_pbd", "sph", "pbd"),
    ("sph_fem", "sph", "fem"),
    ("pbd_fem", "pbd", "fem"),
)


def _mpm_sph(mpm, sph):
    from simcli.coupling.mpm_sph import make_mpm_sph

    return make_mpm_sph(mpm, sph)


def _mpm_pbd(mpm, pbd):
    from simcli.coupling.mpm_pbd import make_mpm_pbd

    return make_mpm_pbd(mpm, pbd)


def _mpm_fem(mpm, fem):
    from simcli.coupling.mpm_fem import make_mpm_fem

    return make_mpm_fem(mpm, fem)


def _sph_fem(sph, fem):
    from simcli.coupling.sph_fem import make_sph_fem

    return make_sph_fem(sph, fem)


def _particles(key):
    def make(a, b):
        from simcli.coupling.particle_pairs import make_particle_pair

        return make_particle_pair(key, a, b)

    return make


IMPLEMENTED: dict[str, Callable] = {
    "mpm_sph": _mpm_sph,
    "mpm_pbd": _mpm_pbd,
    "mpm_fem": _mpm_fem,
    "sph_pbd": _particles("sph_pbd"),
    "sph_fem": _sph_fem,
    "pbd_fem": _particles("pbd_fem"),
}


def make_coupler(scene: Any, solvers: list, warn: Callable[[str], None] | None = None) -> Coupler | None:
    """The coupler of the pairs present and on, made before the solvers are built (a pair may ask a solver
    to keep what it reads, e.g. MPM's node masses); None when nothing is coupled."""
    by_family = {s.family: s for s in solvers}
    if "fem" in by_family and "fem_cloth" in by_family:  # FEM.Cloth meets FEM solids in its own IPC step
        by_family["fem_cloth"].attach_solid(by_family["fem"])
    cfg = getattr(scene, "coupling", None)
    pairs = []
    for key, a, b in PAIRS:
        if a not in by_family or b not in by_family:
            continue
        on = True if cfg is None else bool(getattr(cfg, key))
        if not on:
            continue
        if key not in IMPLEMENTED:
            if warn is not None:
                warn(
                    f"coupling.{key}: {a.upper()} and {b.upper()} entities do not interact yet (this pair is "
                    "not implemented; docs/COUPLING.md)"
                )
            continue
        pairs.append(IMPLEMENTED[key](by_family[a], by_family[b]))
    return Coupler(solvers, pairs) if pairs else None


class Coupler:
    """The substep of a coupled scene: every solver's pre_couple, the pairs, every solver's post_couple."""

    def __init__(self, solvers: list, pairs: list) -> None:
        self.solvers, self.pairs = solvers, pairs
        # pairs that place another family's body in SPH before SPH's substep (sph_fem.py): SPH's pre_couple
        # then runs after every other family's, so that it meets the body where that body's substep left it
        self.before_sph = [p for p in pairs if hasattr(p, "before_sph")]
        self.pre_order = list(solvers)
        if self.before_sph:
            self.pre_order = [s for s in solvers if s.family != "sph"] + [
                s for s in solvers if s.family == "sph"
            ]
        self.profile = False  # sync and time each phase (benchmarks, docs/PERFORMANCE.md)
        self.times = {"pre": 0.0, "couple": 0.0, "post": 0.0}

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.pairs]

    @property
    def methods(self) -> dict[str, str]:
        """Each pair's method (run.json ``coupling_methods``): ``boundary_particles`` (sph_fem.py,
        mpm_sph.py), ``sheet_contact`` (MPM-PBD cloth, rope, soft-body vertices) or ``grid_contact``."""
        return {p.name: str(getattr(p, "method", "grid_contact")) for p in self.pairs}

    def prepare(self) -> None:
        """Before the solvers' build: what a pair must give a solver to build with (sph_fem.py: the FEM
        body's samples as SPH boundary particles)."""
        for p in self.pairs:
            if hasattr(p, "prepare"):
                p.prepare()

    def build(self) -> None:
        """After the solvers' build: the pairs' fields and kernels."""
        for p in self.pairs:
            p.build()

    def memory_bytes(self) -> int:
        return sum(int(getattr(p, "bytes", 0)) for p in self.pairs)

    def substep(self, dt: float) -> None:
        if self.profile:
            return self._substep_timed(dt)
        self._pre(dt)
        for p in self.pairs:
            p.couple(dt)
        for s in self.solvers:
            s.post_couple(dt)

    def _pre(self, dt: float) -> None:
        for s in self.pre_order:
            if s.family == "sph":
                for p in self.before_sph:
                    p.before_sph(dt)
            s.pre_couple(dt)

    def _substep_timed(self, dt: float) -> None:
        import taichi as ti

        t0 = time.perf_counter()
        self._pre(dt)
        ti.sync()
        t1 = time.perf_counter()
        for p in self.pairs:
            p.couple(dt)
        ti.sync()
        t2 = time.perf_counter()
        for s in self.solvers:
            s.post_couple(dt)
        ti.sync()
        t3 = time.perf_counter()
        self.times["pre"] += t1 - t0
        self.times["couple"] += t2 - t1
        self.times["post"] += t3 - t2
