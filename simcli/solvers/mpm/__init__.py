"""MPM solver family (MLS-MPM). ``MPMSolver`` is imported lazily so that importing the package
does not import Taichi."""

from __future__ import annotations

__all__ = ["MPMSolver"]


def __getattr__(name: str):
    if name == "MPMSolver":
        from simcli.solvers.mpm.solver import MPMSolver

        return MPMSolver
    raise AttributeError(name)
