"""MPM <-> PBD: PBD particles (granular, liquid, cloth and rope vertices, soft-body vertices) meet the MPM
grid as the second material of a grid contact (grid_contact.py).

PBD keeps its substep whole (predict, constraints, contacts, velocity update) before the coupling phase; the
contact then reads its particles at the substep's start (``xp``, where the MPM grid was built) with their new
velocities, and moves them by dt times their velocity change so that position and velocity stay consistent.
Pinned and prescribed vertices (inverse mass 0) are not coupled. PBD.Liquid and PBD.Particle carry a volume
(density from the material); cloth and rope vertices do not (contact wherever both are present).
"""

from __future__ import annotations

from typing import Any

import taichi as ti

from simcli.coupling.grid_contact import GridContact, ParticleSet


def make_mpm_pbd(mpm: Any, pbd: Any) -> GridContact:
    mpm.store_node_mass = True
    pair = GridContact(mpm, None, "mpm_pbd")
    dim = mpm.dim

    def build() -> None:
        xp, w = pbd.xp, pbd.w
        f = pbd.f

        @ti.func
        def pos(i):
            return ti.Vector([xp[i][d] for d in ti.static(range(dim))])

        @ti.func
        def m(i):
            r = ti.cast(0.0, f)
            if w[i] > 0:
                r = 1.0 / w[i]
            return r

        ents = [e for e in list(pbd.scene.entities) + list(pbd.scene.emitters) if e.family == "PBD"]
        kinds = {str(e.material.type) for e in ents}
        volumetric = all(k in ("PBD.Liquid", "PBD.Particle") for k in kinds)
        rho = None
        if volumetric:
            rho = min(float(e.material.rho) for e in ents)
        pair.other = ParticleSet(
            n=pbd.n,
            pos=pos,
            mass=m,
            vel=pbd.v,
            vel_dim=3,
            rho=rho,
            move_x=pbd.x,
            shift_x=pbd.x,
            count=pbd.count if pbd.active_set is not None else None,  # emitters, sinks: the active count
        )
        GridContact.build(pair)

    pair.build = build
    return pair
