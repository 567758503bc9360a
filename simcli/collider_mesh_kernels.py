"""Kernel side of `type: Mesh` colliders (simcli.collider_mesh builds the grids, without Taichi) and the
PBD restitution pass. Importing this module imports Taichi (stdout kept clean), without initialising it."""

from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.collider_mesh import FAR, GridSDF

with stdout_to_stderr():
    import taichi as ti

_CORNERS = tuple((a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1))


@ti.func
def grid_cell(x, origin, inv_h, shape: ti.template()):
    """Where world point x falls on a 3D node grid (node 0 at ``origin``, spacing 1 / inv_h, ``shape``
    nodes): (inside the grid, the cell's lower node, the fractions in the cell) for trilinear lookups."""
    g = (x - origin) * inv_h
    inside = True
    for d in ti.static(range(3)):
        if g[d] < 0 or g[d] > shape[d] - 1:
            inside = False
    base = ti.Vector([0, 0, 0])
    f = g * 0.0
    if inside:
        for d in ti.static(range(3)):
            base[d] = ti.min(ti.cast(ti.floor(g[d]), ti.i32), shape[d] - 2)
            f[d] = g[d] - base[d]
    return inside, base, f


def mesh_fields(specs: list, dtype: Any, normal_below: float | None = None) -> list:
    """A MeshSDFField for every Mesh spec (None for the others), allocated now (after ti.init)."""
    return [
        MeshSDFField(s.mesh, dtype, normal_below) if getattr(s, "mesh", None) is not None else None
        for s in specs
    ]


@ti.data_oriented
class MeshSDFField:
    """The grid of a simcli.collider_mesh.GridSDF in a Taichi field; :meth:`sample` gives (phi, unit outward
    normal) at a body-frame point by trilinear interpolation of a MeshSDF (the normal is the interpolant's
    gradient); a 2D grid (simcli.rigid.polygon.PolygonSDF, a 2D Mesh rigid body) bilinearly."""

    def __init__(self, sdf: GridSDF, dtype: Any, normal_below: float | None = None) -> None:
        """``normal_below``: the normal is computed only where phi is below it [m] (None: everywhere);
        callers that use it only inside (phi < 0) skip the gradient elsewhere."""
        self.dtype = dtype
        self.normal_below = normal_below
        # a 2D polygon's grid (a 2D Mesh body): normals everywhere, the MPM image reads them in front
        self.normal_everywhere = normal_below is None or len(sdf.shape) == 2
        self.shape = sdf.shape
        self.origin = tuple(float(v) for v in sdf.origin)
        self.inv_h = 1.0 / sdf.h
        self.phi = ti.field(dtype, shape=self.shape)
        self.phi.from_numpy(sdf.phi.astype(np.float64 if dtype == ti.f64 else np.float32))

    @ti.func
    def sample(self, x):
        phi = ti.cast(FAR, self.dtype)
        n = x * 0.0
        if ti.static(len(self.shape) == 2):  # a 2D polygon's grid (simcli.rigid.polygon): bilinear
            phi, n = self._sample2(x)
        else:
            phi, n = self._sample3(x)
        return phi, n

    @ti.func
    def _sample2(self, x):
        phi = ti.cast(FAR, self.dtype)
        n = ti.Vector([0.0, 1.0], dt=self.dtype)
        g = (x - ti.Vector(self.origin, dt=self.dtype)) * self.inv_h
        inside = True
        for d in ti.static(range(2)):
            if g[d] < 0 or g[d] > self.shape[d] - 1:
                inside = False
        if inside:
            i = ti.min(ti.cast(ti.floor(g[0]), ti.i32), self.shape[0] - 2)
            j = ti.min(ti.cast(ti.floor(g[1]), ti.i32), self.shape[1] - 2)
            fx = g[0] - i
            fy = g[1] - j
            v00 = self.phi[i, j]
            v10 = self.phi[i + 1, j]
            v01 = self.phi[i, j + 1]
            v11 = self.phi[i + 1, j + 1]
            c0 = v00 + fx * (v10 - v00)
            c1 = v01 + fx * (v11 - v01)
            phi = c0 + fy * (c1 - c0)
            need = True
            if ti.static(not self.normal_everywhere):
                need = phi < self.normal_below
            if need:  # the interpolant's gradient
                grad = ti.Vector([(v10 - v00) + fy * ((v11 - v01) - (v10 - v00)), c1 - c0], dt=self.dtype)
                gn = grad.norm()
                if gn > 0:
                    n = grad / gn
        return phi, n

    @ti.func
    def _sample3(self, x):
        phi = ti.cast(FAR, self.dtype)
        n = ti.Vector([0.0, 0.0, 1.0], dt=self.dtype)
        inside, base, f = grid_cell(x, ti.Vector(self.origin, dt=self.dtype), self.inv_h, self.shape)
        if inside:
            vals = ti.Vector.zero(self.dtype, 8)
            for j in ti.static(range(8)):
                a, b, c = ti.static(_CORNERS[j])
                vals[j] = self.phi[base[0] + a, base[1] + b, base[2] + c]
            # trilinear: along x, then y, then z
            c00 = vals[0] + f[0] * (vals[4] - vals[0])
            c01 = vals[1] + f[0] * (vals[5] - vals[1])
            c10 = vals[2] + f[0] * (vals[6] - vals[2])
            c11 = vals[3] + f[0] * (vals[7] - vals[3])
            c0 = c00 + f[1] * (c10 - c00)
            c1 = c01 + f[1] * (c11 - c01)
            phi = c0 + f[2] * (c1 - c0)
            need = True
            if ti.static(not self.normal_everywhere):
                need = phi < self.normal_below
            if need:  # the interpolant's gradient
                grad = ti.Vector([0.0, 0.0, c1 - c0], dt=self.dtype)
                d0 = c10 - c00
                d1 = c11 - c01
                grad[1] = d0 + f[2] * (d1 - d0)
                e00 = vals[4] - vals[0]
                e01 = vals[5] - vals[1]
                e10 = vals[6] - vals[2]
                e11 = vals[7] - vals[3]
                e0 = e00 + f[1] * (e10 - e00)
                e1 = e01 + f[1] * (e11 - e01)
                grad[0] = e0 + f[2] * (e1 - e0)
                gn = grad.norm()
                if gn > 0:
                    n = grad / gn
        return phi, n


# ------------------------------------------------------------------ PBD restitution


@ti.data_oriented
class PBDRestitution:
    """Normal restitution of PBD particles on colliders (velocity pass after XPBD's v = dx / dt, as Müller
    et al. 2020 do): the final contact projection records, per particle, the collider's restitution e, the
    contact normal and the particle's normal velocity relative to the surface before the contact; after
    the velocity update the normal relative velocity becomes -e times that approach speed. Approaches
    slower than 2 |g| dt are left inelastic (a resting particle stays at rest). Allocated and compiled
    only when some collider has restitution > 0."""

    def __init__(self, specs: list, n: int, dtype: Any, v: Any, gravity: float, dim: int = 3) -> None:
        self.es = tuple(float(s.restitution) for s in specs)
        self.any = any(e > 0 for e in self.es)
        self.v = v
        self.gravity = float(gravity)
        if self.any:
            self.e = ti.field(dtype, shape=n)
            self.vn = ti.field(dtype, shape=n)
            self.nrm = ti.Vector.field(dim, dtype, shape=n)
            self.vw = ti.Vector.field(dim, dtype, shape=n)

    @ti.func
    def record(self, i, k: ti.template(), gap, n, vrel, vw):
        if gap < 0:
            self.e[i] = self.es[k]
            self.nrm[i] = n
            self.vn[i] = vrel.dot(n)
            self.vw[i] = vw

    @ti.kernel
    def _apply(self, thr: float):
        for i in self.e:
            e = self.e[i]
            if e > 0:
                vn0 = self.vn[i]
                if vn0 < -thr:
                    n = self.nrm[i]
                    vn_now = (self.v[i] - self.vw[i]).dot(n)
                    self.v[i] += (-e * vn0 - vn_now) * n
                self.e[i] = 0.0

    def apply(self, dt: float) -> None:
        self._apply(2.0 * self.gravity * dt)
