"""Stable-fluids solver family (Stam 1999 on a MAC grid). ``SFSolver`` is imported lazily so that
importing the package does not import Taichi."""

from __future__ import annotations

__all__ = ["SFSolver"]


def __getattr__(name: str):
    if name == "SFSolver":
        from simcli.solvers.sf.solver import SFSolver

        return SFSolver
    raise AttributeError(name)
