"""Scene-level checks of the ``coupling:`` key (no Taichi): a key for a pair of families the scene does not
hold is a warning with its location (it does nothing), never an error. Which pairs exist and which are
implemented is the coupling phase's business (simcli/coupling/phase.py); the keys are the model's fields."""

from __future__ import annotations

from typing import Any

# implemented pairs (simcli/coupling/phase.py IMPLEMENTED; a test keeps the two in step)
IMPLEMENTED_PAIRS = ("mpm_sph", "mpm_pbd", "mpm_fem", "sph_pbd", "sph_fem", "pbd_fem")


def pair_families(key: str) -> tuple[str, str]:
    a, b = key.split("_")
    return a.upper(), b.upper()


def coupled(scene: Any, fam_a: str, fam_b: str) -> bool:
    """Whether entities of families ``fam_a`` and ``fam_b`` (``"MPM"``, ...) interact in this scene."""
    for key in IMPLEMENTED_PAIRS:
        if {fam_a, fam_b} == set(pair_families(key)):
            cfg = scene.coupling
            return cfg is None or bool(getattr(cfg, key))
    return False


def _sph_samples(scene: Any, family: str) -> bool:
    """SPH and ``family`` coupled in a 3D scene with SPH's boundary particles (not volume maps): what both
    rules below ask first."""
    sph = getattr(scene.solvers, "sph", None)
    return (
        coupled(scene, "SPH", family)
        and int(scene.sim.dim) == 3
        and sph is not None
        and getattr(sph, "boundary", "particles") == "particles"
    )


def sph_fem_by_particles(scene: Any) -> bool:
    """Whether SPH meets FEM bodies as boundary particles (simcli/coupling/sph_fem.py: the FEM body sampled
    into SPH's boundary, a 3D scene with SPH's boundary particles), not by the grid contact (volume maps)."""
    return _sph_samples(scene, "FEM")


# MPM materials that meet SPH as boundary particles (mpm_sph_by_particles): solids, whose particles keep their
# neighbours; sand and liquid (which mix with the water, and whose grains the liquid would otherwise fill
# around) keep the grid contact
MPM_SAMPLED = ("MPM.Elastic", "MPM.ElastoPlastic", "MPM.Snow", "MPM.Muscle")


def mpm_sph_by_particles(scene: Any) -> bool:
    """Whether SPH meets the MPM bodies as boundary particles (simcli/coupling/mpm_sph.py: the body sampled on
    SPH's lattice into its boundary), not by the grid contact: a 3D scene with SPH's boundary particles, whose
    MPM entities are all solids (MPM_SAMPLED) with a fixed set of particles (no MPM emitter, no sink) and
    none pinned (``fixed``: a pinned node's velocity is reset every substep, so the liquid's impulse there
    would move the samples and not the body)."""
    ents = [e for e in scene.entities if e.family == "MPM"]
    types = {e.material.type for e in ents}
    return (
        _sph_samples(scene, "MPM")
        and bool(types)
        and types <= set(MPM_SAMPLED)
        and all(getattr(e, "fixed", None) is None for e in ents)
        and not getattr(scene, "sinks", None)
        and not any(em.family == "MPM" for em in getattr(scene, "emitters", None) or [])
    )


# families no coupling pair covers yet: their entities pass through every other family's (a warning says so)
UNCOUPLED = {"FEMCloth": "FEM.Cloth", "SF": "SF"}


def coupling_warnings(loaded: Any) -> list[str]:
    s = loaded.scene
    loc = loaded.located
    fams = s.families
    out = []
    for fam, label in UNCOUPLED.items():
        # (FEM.Cloth meets FEM solids in its own IPC step: simcli/solvers/fem/cloth/solid_obstacles.py)
        others = sorted(f for f in fams if f != fam and not (fam == "FEMCloth" and f == "FEM"))
        if fam not in fams or not others:
            continue
        i = next(k for k, e in enumerate(s.entities) if e.family == fam)
        where = loc.where(("entities", i), prefer_key=True)
        out.append(
            f"{where}: warning: {label} entities do not interact with the "
            f"{', '.join(UNCOUPLED.get(o, o) for o in others)} entities: no coupling "
            f"pair covers {label} yet, so they pass through each other (docs/COUPLING.md)"
        )
    if s.coupling is None:
        return out
    for key in sorted(s.coupling.model_fields_set):
        a, b = pair_families(key)
        missing = [x for x in (a, b) if x not in fams]
        if missing:
            out.append(
                f"{loc.where(('coupling', key), prefer_key=True)}: coupling.{key}: warning: the scene has no "
                f"{' and no '.join(missing)} entity, so this key does nothing (remove it, or add the entity)"
            )
    return out
