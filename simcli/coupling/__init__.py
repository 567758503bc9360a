"""The coupling phase between solver families (docs/COUPLING.md).

``make_coupler(scene, solvers, warn)`` returns a ``Coupler`` when at least one pair of families present in the
scene is coupled (``coupling.<pair>``, every pair on by default), else None: a scene of one family, or with
every pair turned off, then steps exactly as before (``substep`` per solver, the same kernels).

With a coupler, each substep is::

    for s in solvers: s.pre_couple(dt)      # MPM: p2g + grid update; SPH: forces, pressure solve; others: all
    for pair in pairs: pair.couple(dt)      # the only phase that reads more than one family
    for s in solvers: s.post_couple(dt)     # MPM: g2p; SPH: advect; others: nothing
"""

from __future__ import annotations

from simcli.coupling.phase import IMPLEMENTED, PAIRS, Coupler, make_coupler

__all__ = ["IMPLEMENTED", "PAIRS", "Coupler", "make_coupler"]
