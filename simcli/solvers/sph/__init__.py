"""SPH solver family (WCSPH and DFSPH liquids). ``SPHSolver`` is imported lazily so that importing
the package (the scene schema does) does not import Taichi."""

from __future__ import annotations

__all__ = ["SPHSolver"]


def __getattr__(name: str):
    if name == "SPHSolver":
        from simcli.solvers.sph.solver import SPHSolver

        return SPHSolver
    raise AttributeError(name)
