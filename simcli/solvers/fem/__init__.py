"""FEM solver family (linear tetrahedra, explicit and implicit). ``FEMSolver`` is imported lazily so
that importing the package (the config half) does not import Taichi."""

from __future__ import annotations

__all__ = ["FEMSolver"]


def __getattr__(name: str):
    if name == "FEMSolver":
        from simcli.solvers.fem.solver import FEMSolver

        return FEMSolver
    raise AttributeError(name)
