"""SPH <-> FEM: the FEM body as boundary particles of the liquid (Akinci et al. 2012, "Versatile rigid-fluid
coupling for incompressible SPH", two-way), as SPH's rigid bodies are; docs/COUPLING.md says why.

Sampling (numpy, at the pair's making, before the solvers' build): per FEM entity, the lattice of SPH's
particle spacing fitted to the body's rest bounding box (points at the cells' centres, as SPH samples a Box
collider, boundary.collider_particles), kept where it lies inside the rest tet mesh and within the
boundary's layers (the kernel's support) of its surface. Each sample keeps its tetrahedron's four corners
and its barycentric weights w_a (from the rest shape's inverse edge matrix), and the lattice cell's volume.

Per substep (the coupler runs SPH's pre_couple after the FEM's): ``before_sph`` places the samples where the
body's substep left it (x_s = sum_a w_a x_a, v_s = sum_a w_a v_a); SPH treats them as a collider's boundary
particles in its density, pressure and wall-pressure sums (deformable.py) and sums, per sample, the impulse
its pressure gave the liquid, reversed (the named colliders' load, moving.make_loads), J_s; ``couple`` gives
each free FEM vertex a its share, dv_a = sum_s w_a J_s / m_a, and its end position dt dv_a (as the grid
contacts move an advanced position), so that the liquid's momentum change and the body's are equal and
opposite. The liquid next to the body is not a free surface to SPH (it was with the grid contact
of particle_contact.py, which made a light body float a cell high and let the liquid creep under a slab).
Held FEM components take no impulse. Contact is frictionless (the samples are slip boundaries).
"""

import math
from typing import Any

import numpy as np
import taichi as ti

from simcli.coupling.samples import box_lattice, surface_band
from simcli.geometry.tetmesh import locate_in_tets, points_in_tets
from simcli.solvers.sph.deformable import DeformableBoundary


def fem_boundary_samples(
    fem: Any, spacing: float, depth: float
) -> "tuple[np.ndarray, np.ndarray, np.ndarray]":
    """(corners (n, 4) int, weights (n, 4), volumes (n,)): the lattice points of ``spacing`` inside each FEM
    entity's rest mesh and within ``depth`` of its surface (see the module docstring). The depth is counted
    on the lattice: a point's distance to the nearest lattice point outside the mesh (a Euclidean distance
    transform), which is its distance to the surface plus half a spacing for a box fitted to the lattice."""
    x0, T, B = fem.x0, fem.tets, fem.B
    corners, weights, volumes = [], [], []
    for k in range(len(fem.entities)):
        tk = T[fem.toffsets[k] : fem.toffsets[k + 1]]
        Bk = B[fem.toffsets[k] : fem.toffsets[k + 1]]
        verts = np.unique(tk)
        lo, hi = x0[verts].min(axis=0), x0[verts].max(axis=0)
        p, n, s = box_lattice(lo, hi, spacing)
        # the tetrahedron holding each point and its barycentric weights (the rest shape's edge matrices);
        # points of the box outside a non-box mesh hold none
        tet, lam = locate_in_tets(x0, tk, p, k=32, tol=1e-9, binv=Bk)
        keep = surface_band(tet >= 0, n, s, depth)
        wk = np.clip(lam[keep], 0.0, 1.0)
        corners.append(tk[tet[keep]])
        weights.append(wk / wk.sum(axis=1, keepdims=True))
        volumes.append(np.full(int(keep.sum()), float(np.prod(s))))
    if not corners:
        return np.zeros((0, 4), np.int64), np.zeros((0, 4)), np.zeros(0)
    return np.concatenate(corners), np.concatenate(weights), np.concatenate(volumes)


class SPHFEMBoundary:
    """The sph_fem pair by boundary particles (made before the solvers' build; ``prepare``, also before it,
    samples the body and attaches the samples to SPH, whose build allocates them)."""

    name = "sph_fem"
    method = "boundary_particles"

    def __init__(self, sph: Any, fem: Any) -> None:
        self.sph, self.fem = sph, fem
        self.n = 0
        self.bytes = 0

    def prepare(self) -> None:
        from simcli.solvers.sph.boundary import LAYERS

        sph, fem = self.sph, self.fem
        # liquid sampled inside the body at the start would sit among its samples (a pressure blow-up):
        # removed with a warning, as SPH removes particles sampled inside a collider
        names = ", ".join(f"'{e.name}'" for e in fem.entities)
        sph.remove_inside(
            lambda p: points_in_tets(fem.xstart, fem.tets, p),
            f"the FEM {'entity' if len(fem.entities) == 1 else 'entities'} {names}",
        )
        layers = max(LAYERS, math.ceil(sph.support / sph.ps - 1e-9))
        idx, w, vol = fem_boundary_samples(fem, sph.ps, layers * sph.ps)
        self.idx, self.w = idx.astype(np.int32), w
        x = np.einsum("na,nad->nd", w, fem.xstart[idx]) if len(idx) else np.zeros((0, 3))
        v = np.einsum("na,nad->nd", w, fem.v0[idx]) if len(idx) else np.zeros((0, 3))
        self.db = DeformableBoundary("FEM", x, vol, v)
        sph.attach_deformable(self.db)
        self.n = self.db.n

    def build(self) -> None:
        fem, db = self.fem, self.db
        f = fem.f
        n = max(1, self.n)
        self.idx_f = ti.Vector.field(4, ti.i32, shape=n)
        self.w_f = ti.Vector.field(4, f, shape=n)
        if self.n:
            self.idx_f.from_numpy(self.idx)
            self.w_f.from_numpy(self.w.astype(fem.npf))
        # per sample: four corner indices and weights here; position, velocity (SPH's precision) and an f64
        # impulse in SPH (SPH's boundary particle fields besides)
        fb = 8 if f == ti.f64 else 4
        self.bytes = self.n * (4 * 4 + 4 * fb + 2 * 3 * fb + 3 * 8)
        x, v, mass, free = fem.x, fem.v, fem.mass_f, fem.free_f
        sx, sv, simp = db.sx, db.sv, db.simp
        idx_f, w_f = self.idx_f, self.w_f
        ns = self.n
        off = db.offset  # its first sample in SPH's samples (another body may share them: deformable.py)

        @ti.kernel
        def couple(dt: f):
            for s in range(ns):  # the liquid's impulse on each sample, to its tetrahedron's corners
                J = ti.cast(simp[off + s], f)
                simp[off + s] = ti.Vector.zero(ti.f64, 3)
                for a in ti.static(range(4)):
                    k = idx_f[s][a]
                    dv = (w_f[s][a] / mass[k]) * J * free[k]
                    ti.atomic_add(v[k], dv)
                    ti.atomic_add(x[k], dt * dv)

        @ti.kernel
        def place():
            for s in range(ns):  # the samples where the body's substep left them, before SPH's
                xs = ti.Vector.zero(f, 3)
                vs = ti.Vector.zero(f, 3)
                for a in ti.static(range(4)):
                    k = idx_f[s][a]
                    xs += w_f[s][a] * x[k]
                    vs += w_f[s][a] * v[k]
                sx[off + s] = xs
                sv[off + s] = vs

        self._couple, self._place = couple, place

    def before_sph(self, dt: float) -> None:
        if self.n:
            self._place()

    def couple(self, dt: float) -> None:
        if self.n:
            self._couple(dt)


def make_sph_fem(sph: Any, fem: Any):
    """The SPH-FEM pair: boundary particles (this module) with SPH's boundary particles; with volume maps
    (no boundary particles to add the body to) the grid contact of particle_contact.py."""
    opts = getattr(sph, "opts", None)
    if opts is None or (opts.boundary == "particles" and sph.dim == 3):
        return SPHFEMBoundary(sph, fem)
    from simcli.coupling.particle_pairs import make_particle_pair

    return make_particle_pair("sph_fem", sph, fem)
