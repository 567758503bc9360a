"""MPM <-> FEM: the FEM mesh's vertices (their lumped masses) meet the MPM grid as the second material of a
grid contact (grid_contact.py), as PBD's particles do.

FEM keeps its substep whole before the coupling phase (explicit: element forces and the vertex update;
implicit: the whole Newton solve), so the contact reads the vertices at the substep's end with their new
velocities; each vertex's velocity change is applied after the FEM step and its position moved by dt times
it, so that position and velocity stay consistent (a splitting: the elastic response to the contact impulse
comes in the next substep, for both integrators; the impulse itself is exact, momentum is conserved). Held
vertices (a fixed region or a velocity condition on any component) are not coupled. The vertices carry a
volume (FEM's density): the contact normal is the average of both materials' (Nairn 2013). The mesh should be
about as fine as MPM's grid (an edge at most ~2 cells): a vertex splats its mass over 3 cells, so a coarser
mesh leaves holes between its vertices that MPM particles slip through.
"""

from __future__ import annotations

from typing import Any

import taichi as ti

from simcli.coupling.grid_contact import GridContact, ParticleSet


def fem_particle_set(fem: Any) -> ParticleSet:
    """FEM's vertices as a particle set (after its build): end positions, lumped masses, held ones 0."""
    x, mass, free = fem.x, fem.mass_f, fem.free_f
    f = fem.f

    @ti.func
    def pos(i):
        return x[i]

    @ti.func
    def m(i):
        r = ti.cast(0.0, f)
        fr = free[i]
        if fr[0] * fr[1] * fr[2] > 0:
            r = mass[i]
        return r

    return ParticleSet(
        n=fem.n,
        pos=pos,
        mass=m,
        vel=fem.v,
        vel_dim=3,
        rho=min(float(mt.rho) for mt in fem.materials),
        move_x=fem.x,
        shift_x=fem.x,
        overlap_tol=0.0,
    )


def make_mpm_fem(mpm: Any, fem: Any) -> GridContact:
    mpm.store_node_mass = True
    pair = GridContact(mpm, None, "mpm_fem")

    def build() -> None:
        pair.other = fem_particle_set(fem)
        GridContact.build(pair)

    pair.build = build
    return pair
