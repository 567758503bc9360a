"""MPM <-> SPH: SPH particles meet the MPM grid as the second material of a grid contact (grid_contact.py).

Phase order: MPM p2g + grid_update | SPH neighbours, forces and pressure solve (the velocity at the substep's
end) -> couple on the MPM grid (both velocities edited) -> MPM g2p | SPH advect. docs/COUPLING.md says why
this method and not Genesis's average-and-replace or Akinci boundary particles.
"""

from __future__ import annotations

from typing import Any

import taichi as ti

from simcli.coupling.grid_contact import GridContact, ParticleSet


def sph_particle_set(sph: Any) -> ParticleSet:
    """SPH's particles as one set of a contact (built after the solver): positions at the substep's start,
    the velocity at its end (before advect), the active count; the overlap correction moves their start."""
    x, mass = sph.x, sph.mass

    @ti.func
    def pos(i):
        return x[i]

    @ti.func
    def m(i):
        return mass[i]

    return ParticleSet(
        n=sph.n,
        pos=pos,
        mass=m,
        vel=sph.couple_velocity,
        vel_dim=sph.dim,
        rho=min(float(mt.rho) for mt in sph.materials),
        count=sph.count,  # the active count (emitters, sinks)
        shift_x=x,  # before advect: the overlap correction moves the start position
    )


def make_mpm_sph(mpm: Any, sph: Any) -> GridContact:
    mpm.store_node_mass = True
    pair = GridContact(mpm, None, "mpm_sph")  # the particle set needs SPH's fields: made in build

    def build() -> None:
        pair.other = sph_particle_set(sph)
        GridContact.build(pair)

    pair.build = build
    return pair
