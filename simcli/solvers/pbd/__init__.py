"""PBD solver family (XPBD cloth and rods). ``PBDSolver`` is imported lazily so that importing the
package (the config half) does not import Taichi."""

from __future__ import annotations

__all__ = ["PBDSolver"]


def __getattr__(name: str):
    if name == "PBDSolver":
        from simcli.solvers.pbd.solver import PBDSolver

        return PBDSolver
    raise AttributeError(name)
