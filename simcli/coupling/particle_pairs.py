"""SPH <-> PBD, SPH <-> FEM and PBD <-> FEM: two particle families in contact on a background grid of the
pair's own (particle_contact.py; docs/COUPLING.md says why this method).

What each family exposes (built after its solver): SPH its particles at the substep's start with the velocity
at its end (before advect: post_couple moves them with the edited velocity); PBD its particles at the
substep's start (``xp``) with their new velocities, end positions moved by dt times the change; FEM its
vertices at the substep's end (mpm_fem.fem_particle_set). Pinned PBD particles and held FEM vertices are not
coupled. The overlap correction moves the liquid or granular set (SPH; PBD.Liquid/PBD.Particle against FEM),
never a cloth; FEM only against a volumeless PBD set it cannot be computed for (then none).
"""

from __future__ import annotations

from typing import Any

import taichi as ti

from simcli.coupling.grid_contact import ParticleSet, pbd_vertex_mass
from simcli.coupling.mpm_fem import fem_particle_set
from simcli.coupling.mpm_sph import sph_particle_set
from simcli.coupling.particle_contact import ParticleContact


def pbd_particle_set(pbd: Any) -> ParticleSet:
    xp = pbd.xp

    @ti.func
    def pos(i):
        return xp[i]

    m = pbd_vertex_mass(pbd)

    ents = [e for e in pbd.scene.entities if e.family == "PBD"]
    # particles and soft bodies (tet meshes: lumped vertex masses, as FEM's) fill space; cloth and rods do not
    volumetric = all(m.kind in ("particles", "tets") for m in pbd.meshes)
    rho = min(float(e.material.rho) for e in ents) if volumetric else None
    return ParticleSet(
        n=pbd.n, pos=pos, mass=m, vel=pbd.v, vel_dim=pbd.dim, rho=rho, move_x=pbd.x, shift_x=pbd.x
    )


def _spacing(solver: Any) -> float:
    fam = solver.family
    if fam == "sph":
        return float(solver.ps)
    if fam == "pbd":
        return float(max(solver.edge, solver.opts.particle_size))
    return float(solver.edge)  # FEM: the mean edge length


def _sets(solver: Any) -> ParticleSet:
    return {"sph": sph_particle_set, "pbd": pbd_particle_set, "fem": fem_particle_set}[solver.family](solver)


def make_particle_pair(key: str, a: Any, b: Any) -> ParticleContact:
    """The pair (made before the solvers' build; its grid and sets are made in build, after theirs)."""
    pair = ParticleContact(key)

    def build() -> None:
        scene = a.scene
        dim = scene.sim.dim
        lo, hi = scene.domain.bounds(dim)
        pair.configure(dim, scene.sim.precision, lo, hi, max(_spacing(a), _spacing(b)))
        pair.a, pair.b = _sets(a), _sets(b)
        if a.family == "sph":  # the liquid moves out of the other
            pair.shift = "a"
        elif pair.a.rho is not None and b.family == "fem":  # PBD grains, liquid or soft body out of FEM
            pair.shift = "a"
        ParticleContact.build(pair)

    pair.build = build
    return pair
