"""FEM solids (FEM.Elastic, FEM.Muscle entities in the same scene) against FEM.Cloth, staggered: the solid's
boundary triangles join the cloth's ipctk collision mesh as obstacle vertices whose positions are
prescribed over the cloth's substep, from where the cloth last met them to the FEM solver's positions at
the substep's end (the FEM solver steps first when it comes first in the scene; otherwise its positions
extrapolated with its velocities), on straight lines per vertex (the path the CCD checks, as a moving Mesh
collider's). After the cloth's substep the contact's reaction on those vertices (minus the barrier's and
friction's gradient there: exactly minus the contact impulse the cloth received) is added to the solid's
vertex velocities as J / m (held components excepted), so momentum is exchanged exactly.

IPC's no-intersection guarantee holds within the cloth's step against the solid's prescribed surface; the
solid's own step meets the cloth only through those impulses, so across the stagger the solid's surface can
move into the cloth (its next substep's positions are reached only as far as the cloth's CCD lets them: a
pinched cloth holds the obstacle back, and the solid's reported surface is then ahead of the one the cloth
met). The verify case counts crossings against the solid's recorded surface at every frame.
"""

from __future__ import annotations

import numpy as np


class SolidSurface:
    """The boundary triangles of an FEM solver's tetrahedral entities (corner tets; tet10's edge nodes are
    left out: their faces are flat between the corners in this contact)."""

    def __init__(self, fem):
        from simcli.geometry.tetmesh import boundary_faces

        self.fem = fem
        faces = boundary_faces(np.asarray(fem.tets, np.int64), np.asarray(fem.x0, float))
        self.ids = np.unique(faces)
        remap = np.full(int(fem.n), -1, np.int64)
        remap[self.ids] = np.arange(len(self.ids))
        self.T = remap[faces]
        self.V0 = np.asarray(fem.x0, float)[self.ids]
        self.m = len(self.ids)
        self.lo = self.hi = 0  # the obstacle-vertex range (set by the cloth solver)
        self._free = None

    def target(self, t_end: float, dt: float) -> np.ndarray:
        """The surface's positions at t_end: the FEM solver's own when it has stepped there, else its
        positions extrapolated with its velocities."""
        fem = self.fem
        x = fem.x.to_numpy().astype(np.float64)[self.ids]
        if fem.time >= t_end - 1e-9 * max(dt, 1e-300):
            return x
        v = fem.v.to_numpy().astype(np.float64)[self.ids]
        return x + (t_end - fem.time) * v

    def apply(self, force: np.ndarray, dt: float) -> None:
        """Add the impulse dt force (m, 3) to the surface vertices' velocities (held components kept)."""
        fem = self.fem
        if self._free is None:
            self._free = fem.free_f.to_numpy().astype(np.float64)[self.ids]
        v = fem.v.to_numpy()
        dv = dt * force / np.asarray(fem.mass, float)[self.ids, None] * self._free
        v[self.ids] = (v[self.ids].astype(np.float64) + dv).astype(v.dtype)
        fem.v.from_numpy(v)
        fem._version = getattr(fem, "_version", 0) + 1
