"""MPM <-> SPH, by one of two methods (docs/COUPLING.md says why each):

- **Boundary particles** (``MPMSPHBoundary``; 3D, SPH's boundary particles, MPM solids only: the scene rule is
  simcli.scene.coupling.mpm_sph_by_particles). The MPM body is sampled as SPH's boundary (Akinci et al. 2012,
  as SPH's rigid bodies and the FEM bodies of sph_fem.py are), so that the liquid next to it is not a free
  surface to SPH. The samples lie on SPH's own lattice (samples.py: the lattice of SPH's spacing fitted to
  the body's box, the points inside the body within the kernel's support of its surface), not at the MPM
  particles: a boundary sampled finer than the liquid holds the liquid off by a fraction of a spacing more
  (measured: an FEM slab sampled at half SPH's spacing floats 10% high; an MPM slab with its 6.4 mm particles
  as samples 3.4% high, with these samples 2.0%: docs/COUPLING.md). Each sample is a passive marker of the
  MPM body, moved by MPM's grid: before SPH's substep (SPH's pre_couple runs after MPM's p2g and grid
  update) ``before_sph`` moves it as g2p moves a particle, v_s = sum_i w_is v_i (the grid's updated
  velocity), x_s += dt v_s. SPH sums the impulse its pressure gave the liquid, reversed, per sample (J_s,
  f64); ``couple`` spreads each over the sample's nodes as MPM spreads a force, dv_i = sum_s w_is J_s / m_i
  (m_i the node's mass), before g2p: the nodes' momentum changes by sum_s J_s, which g2p hands to the
  particles (APIC and PIC keep the grid's momentum; FLIP's increment carries it); then it moves each sample
  again from where it started, with the impulses in, as g2p will move the particles (a sample that kept the
  velocity before them lagged its body by dt^2 |dv| a substep, and drifted out of it). Frictionless, as the
  walls' slip.
- **Grid contact** (otherwise: 2D, volume maps, sand or liquid MPM, MPM emitters or sinks, pinned MPM):
  SPH particles meet the MPM grid as the second material of a grid contact (grid_contact.py). Phase order:
  MPM p2g + grid_update | SPH neighbours, forces and pressure solve (the velocity at the substep's end) ->
  couple on the MPM grid (both velocities edited) -> MPM g2p | SPH advect.
"""

import math
from typing import Any

import numpy as np
import taichi as ti

from simcli.coupling.grid_contact import GridContact, ParticleSet
from simcli.scene.coupling import mpm_sph_by_particles
from simcli.solvers.mpm.stencil import build_stencil
from simcli.solvers.sph.deformable import DeformableBoundary


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


class ParticleBody:
    """An MPM body's particles at the start, as the samples need them: their spacing ``h`` [m] (the median
    distance to the nearest neighbour on a lattice, whose particles' volumes are scaled to the shape's, a
    little off the lattice's cell; else vol^(1/dim)), ``inside(p)`` (within a particle's cell, max-norm half
    the spacing, more for jittered or Poisson-disk particles; a point on the face between two cells, where
    SPH's lattice at twice the particles' spacing lands, counts: the reach is 5% over the half) and
    ``nearest(p)`` (the index of the nearest particle). One k-d tree per body."""

    def __init__(self, mpm: Any, b: Any) -> None:
        from scipy.spatial import cKDTree

        self.x = np.asarray(b.x, np.float64)
        self.v = np.asarray(b.v, np.float64)
        self.tree = cKDTree(self.x)
        lattice = getattr(mpm.scene.solvers.mpm, "sampling", "lattice") == "lattice"
        if lattice and len(self.x) > 1:
            d, _ = self.tree.query(self.x, k=2)
            self.h = float(np.median(d[:, 1]))
        else:
            self.h = float(np.median(b.volume)) ** (1.0 / mpm.dim)
        self.reach = (0.525 if lattice else 0.8) * self.h

    def inside(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        if not len(p):
            return np.zeros(0, bool)
        d, _ = self.tree.query(p, p=np.inf)
        return d < self.reach

    def nearest(self, p: np.ndarray) -> np.ndarray:
        return self.tree.query(np.asarray(p, dtype=np.float64))[1]


def particle_bodies(mpm: Any) -> "list[ParticleBody]":
    return [ParticleBody(mpm, b) for b in mpm.bodies if b.n]


def mpm_boundary_samples(
    mpm: Any, spacing: float, depth: float, bodies: "list[ParticleBody] | None" = None
) -> "tuple[np.ndarray, np.ndarray, np.ndarray]":
    """(positions (m, 3), velocities (m, 3), volumes (m,)): per MPM body (``bodies``, made here if not given),
    the lattice of ``spacing`` fitted to its box (its particles' extent plus half their spacing) kept where it
    lies in the body and within ``depth`` of its surface; each point takes its nearest particle's velocity."""
    from simcli.coupling.samples import box_lattice, surface_band

    xs, vs, vols = [], [], []
    for pb in particle_bodies(mpm) if bodies is None else bodies:
        lo, hi = pb.x.min(axis=0) - 0.5 * pb.h, pb.x.max(axis=0) + 0.5 * pb.h
        p, n, s = box_lattice(lo, hi, spacing)
        keep = surface_band(pb.inside(p), n, s, depth)
        xs.append(p[keep])
        vs.append(pb.v[pb.nearest(p[keep])])
        vols.append(np.full(int(keep.sum()), float(np.prod(s))))
    if not xs:
        z = np.zeros((0, mpm.dim))
        return z, z, np.zeros(0)
    return np.concatenate(xs), np.concatenate(vs), np.concatenate(vols)


class MPMSPHBoundary:
    """The mpm_sph pair by boundary particles (see the module docstring); made before the solvers' build,
    ``prepare`` (also before it) attaches the samples to SPH, ``build`` after it."""

    name = "mpm_sph"
    method = "boundary_particles"

    def __init__(self, mpm: Any, sph: Any) -> None:
        self.mpm, self.sph = mpm, sph
        mpm.store_node_mass = True  # couple divides by the nodes' masses
        self.n = 0
        self.bytes = 0

    def prepare(self) -> None:
        from simcli.solvers.sph.boundary import LAYERS

        mpm, sph = self.mpm, self.sph
        # liquid sampled inside the body at the start would sit among its samples: removed with a warning,
        # as for a collider
        bodies = particle_bodies(mpm)

        def inside(p):
            out = np.zeros(len(p), bool)
            for pb in bodies:
                out |= pb.inside(p)
            return out

        names = ", ".join(f"'{b.name}'" for b in mpm.bodies)
        sph.remove_inside(inside, f"the MPM {'entity' if len(mpm.bodies) == 1 else 'entities'} {names}")
        layers = max(LAYERS, math.ceil(sph.support / sph.ps - 1e-9))
        x, v, vol = mpm_boundary_samples(mpm, sph.ps, layers * sph.ps, bodies)
        self.db = DeformableBoundary("MPM", x, vol, v)
        sph.attach_deformable(self.db)
        self.n = self.db.n

    def build(self) -> None:
        mpm, db = self.mpm, self.db
        dim, f = mpm.dim, mpm.f
        fb = 8 if f == ti.f64 else 4
        self.bytes = self.n * (2 * dim * fb + dim * 8)  # SPH's sample position, velocity, f64 impulse
        grid_v, grid_m = mpm.grid_v, mpm.grid_m
        sx, sv, simp = db.sx, db.sv, db.simp
        off, ns = db.offset, self.n
        bspline = build_stencil(mpm.params).bspline  # MPM's quadratic B-spline stencil, as p2g and g2p

        x0 = ti.Vector.field(dim, f, shape=max(1, ns))  # each sample's place at the substep's start
        self.bytes += self.n * dim * fb
        stencil = [3] * dim

        @ti.func
        def weight(w: ti.template(), o: ti.template()):  # the stencil node o's weight (o static)
            wt = ti.cast(1.0, f)
            for d in ti.static(range(dim)):
                wt *= w[o[d]][d]
            return wt

        @ti.func
        def grid_velocity(xs):
            base, _, w = bspline(xs)
            vs = ti.Vector.zero(f, dim)
            for o in ti.static(ti.grouped(ti.ndrange(*stencil))):
                vs += weight(w, o) * grid_v[base + o]
            return vs

        @ti.kernel
        def place(dt: f):
            for s in range(ns):  # each sample moved as g2p moves a particle, by the grid's velocity there
                xs = sx[off + s]
                x0[s] = xs
                vs = grid_velocity(xs)
                sx[off + s] = xs + dt * vs
                sv[off + s] = vs

        @ti.kernel
        def spread():
            for s in range(ns):  # the liquid's impulse on each sample, spread over its nodes
                J = ti.cast(simp[off + s], f)
                simp[off + s] = ti.Vector.zero(ti.f64, dim)
                base, _, w = bspline(x0[s])
                for o in ti.static(ti.grouped(ti.ndrange(*stencil))):
                    I = base + o
                    m = grid_m[I]
                    if m > 0:
                        ti.atomic_add(grid_v[I], (weight(w, o) / m) * J)

        @ti.kernel
        def follow(dt: f):
            for s in range(ns):  # moved again with the impulses in, as g2p will move the particles: a
                # sample that kept the velocity before them would lag its body by dt^2 |dv| per substep
                vs = grid_velocity(x0[s])
                sx[off + s] = x0[s] + dt * vs
                sv[off + s] = vs

        def couple(dt):
            spread()
            follow(dt)

        self._place, self._couple = place, couple

    def before_sph(self, dt: float) -> None:
        if self.n:
            self._place(dt)

    def couple(self, dt: float) -> None:
        if self.n:
            self._couple(dt)


def make_mpm_sph(mpm: Any, sph: Any):
    """The MPM-SPH pair: boundary particles where the scene allows them (the module docstring), else the grid
    contact."""
    if getattr(sph, "opts", None) is not None and mpm_sph_by_particles(mpm.scene):
        return MPMSPHBoundary(mpm, sph)
    mpm.store_node_mass = True
    pair = GridContact(mpm, None, "mpm_sph")  # the particle set needs SPH's fields: made in build

    def build() -> None:
        pair.other = sph_particle_set(sph)
        GridContact.build(pair)

    pair.build = build
    return pair
