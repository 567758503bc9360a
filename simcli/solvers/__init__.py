"""Solver families. ``make_solvers`` builds only the families some entity uses.

A family is registered here by the material-type prefix its entities use ("MPM", "SPH", ...)
and the import path of its solver class; a family no entity uses is never imported,
allocated or compiled.
"""

from __future__ import annotations

import importlib

FAMILIES: dict[str, str] = {
    "MPM": "simcli.solvers.mpm.solver:MPMSolver",
    "SPH": "simcli.solvers.sph.solver:SPHSolver",
    "SF": "simcli.solvers.sf.solver:SFSolver",
    "FEM": "simcli.solvers.fem.solver:FEMSolver",
    "PBD": "simcli.solvers.pbd.solver:PBDSolver",
    "FEMCloth": "simcli.solvers.fem.cloth.solver:ClothSolver",  # FEM.Cloth entities
}


def make_solvers(scene, bodies, scene_dir=None) -> list:
    """One solver per family present in the scene, in order of first appearance."""
    families: list[str] = []
    for e in list(scene.entities) + list(getattr(scene, "emitters", [])):  # an emitter's family too
        if e.family not in families:
            families.append(e.family)
    solvers = []
    for fam in families:
        if fam not in FAMILIES:  # the schema only admits implemented families
            raise NotImplementedError(f"solver family {fam} is not available")
        mod, cls = FAMILIES[fam].split(":")
        solver_cls = getattr(importlib.import_module(mod), cls)
        # particle families get their sampled bodies; grid families (SF) read the scene itself
        mine = [b for b in bodies if b.entity.family == fam]
        # files named in the scene (meshes, motion CSVs) resolve against its folder
        solvers.append(solver_cls(scene, mine, scene_dir=scene_dir))
    return solvers
