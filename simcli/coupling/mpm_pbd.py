"""MPM <-> PBD: PBD particles (granular, liquid, cloth and rope vertices, soft-body vertices) meet the MPM
material.

PBD keeps its substep whole (predict, constraints, contacts, velocity update) before the coupling phase.

- Grains and liquid particles (every PBD entity a PBD.Liquid or PBD.Particle) carry a volume (density from the
  material): they are the second material of a grid contact (grid_contact.py). The contact reads them at the
  substep's start (``xp``, where the MPM grid was built) with their new velocities, and moves them by dt times
  their velocity change so that position and velocity stay consistent.
- Otherwise (cloth, rope, soft-body vertices: a set without volume) each vertex is kept out of the MPM
  material by a one-sided contact on its end position against MPM's volume fraction, its reaction given to
  MPM's nodes (sheet_contact.py): the grid merge cannot hold a sheet (a ball drags the light cloth's vertices
  along and passes through it; a cloth on sand stops a cell and a half above it; docs/COUPLING.md).

Pinned and prescribed vertices (inverse mass 0) are not coupled.
"""

from __future__ import annotations

from typing import Any

import taichi as ti

from simcli.coupling.grid_contact import GridContact, ParticleSet, pbd_vertex_mass
from simcli.coupling.sheet_contact import SheetContact


def _volumetric(pbd: Any) -> bool:
    ents = [e for e in list(pbd.scene.entities) + list(pbd.scene.emitters) if e.family == "PBD"]
    return all(str(e.material.type) in ("PBD.Liquid", "PBD.Particle") for e in ents)


class MpmPbd:
    """The pair: which contact is chosen at build (when PBD knows its bodies), then that contact's calls."""

    name = "mpm_pbd"

    def __init__(self, mpm: Any, pbd: Any) -> None:
        self.mpm, self.pbd = mpm, pbd
        mpm.store_node_mass = True  # both contacts read MPM's node masses
        self.contact: GridContact | SheetContact | None = None

    @property
    def bytes(self) -> int:
        return int(getattr(self.contact, "bytes", 0))

    @property
    def method(self) -> str:
        return "sheet_contact" if isinstance(self.contact, SheetContact) else "grid_contact"

    def build(self) -> None:
        self.contact = _grid(self.mpm, self.pbd) if _volumetric(self.pbd) else _sheet(self.mpm, self.pbd)

    def couple(self, dt: float) -> None:
        self.contact.couple(dt)


def make_mpm_pbd(mpm: Any, pbd: Any) -> MpmPbd:
    return MpmPbd(mpm, pbd)


def _grid(mpm: Any, pbd: Any) -> GridContact:
    dim = mpm.dim
    xp = pbd.xp

    @ti.func
    def pos(i):
        return ti.Vector([xp[i][d] for d in ti.static(range(dim))])

    m = pbd_vertex_mass(pbd)

    ents = [e for e in list(pbd.scene.entities) + list(pbd.scene.emitters) if e.family == "PBD"]
    rho = min(float(e.material.rho) for e in ents)
    other = ParticleSet(
        n=pbd.n,
        pos=pos,
        mass=m,
        vel=pbd.v,
        vel_dim=pbd.dim,
        rho=rho,
        move_x=pbd.x,
        shift_x=pbd.x,
        count=pbd.count if pbd.active_set is not None else None,  # emitters, sinks: the active count
    )
    pair = GridContact(mpm, other, "mpm_pbd")
    pair.build()
    return pair


def _sheet(mpm: Any, pbd: Any) -> SheetContact:
    m = pbd_vertex_mass(pbd)

    count = pbd.count if pbd.active_set is not None else None
    sweeps = [k for k in (pbd._solve_stretch, pbd._solve_volume) if k is not None]

    def relax(dt: float) -> None:  # one more Gauss-Seidel sweep of the bodies' stretch (and volume)
        if pbd.serial:  # small bodies: one single-threaded launch, as PBD's own step (the same sweep order)
            pbd._project_serial(dt, 1, 0)
        else:
            for k in sweeps:
                k(dt)

    pair = SheetContact(mpm, "mpm_pbd")
    pair.build(pbd.n, m, pbd.x, pbd.xp, pbd.v, count, relax if sweeps else None)
    return pair
