"""Solver families. ``make_solvers`` builds only the families some entity uses."""

from __future__ import annotations


def make_solvers(scene, bodies) -> list:
    """One solver per family present in the scene (imported lazily: a family no entity
    uses is never imported, allocated or compiled)."""
    families = []
    for e in scene.entities:
        if e.family not in families:
            families.append(e.family)
    solvers = []
    for fam in families:
        if fam == "MPM":
            from simcli.solvers.mpm.solver import MPMSolver

            solvers.append(MPMSolver(scene, [b for b in bodies if b.entity.family == "MPM"]))
        else:  # the schema only admits implemented families; this is a programming error
            raise NotImplementedError(f"solver family {fam} is not available")
    return solvers
