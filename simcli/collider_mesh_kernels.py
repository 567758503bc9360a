"""Kernel side of `type: Mesh` colliders (simcli.collider_mesh builds the grids, without Taichi) and the
PBD restitution pass. Importing this module imports Taichi (stdout kept clean), without initialising it."""

from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.collider_mesh import FAR, MeshSDF

with stdout_to_stderr():
    import taichi as ti

_CORNERS = tuple((a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1))


def mesh_fields(specs: list, dtype: Any) -> list:
    """A MeshSDFField for every Mesh spec (None for the others), allocated now (after ti.init)."""
    return [MeshSDFField(s.mesh, dtype) if getattr(s, "mesh", None) is not None else None for s in specs]


@ti.data_oriented
class MeshSDFField:
    """The grid of a MeshSDF in a Taichi field; :meth:`sample` gives (phi, unit outward normal) at a
    body-frame point by trilinear interpolation (the normal is the interpolant's gradient)."""

    def __init__(self, sdf: MeshSDF, dtype: Any) -> None:
        self.dtype = dtype
        self.shape = sdf.shape
        self.origin = tuple(float(v) for v in sdf.origin)
        self.inv_h = 1.0 / sdf.h
        self.phi = ti.field(dtype, shape=self.shape)
        self.phi.from_numpy(sdf.phi.astype(np.float64 if dtype == ti.f64 else np.float32))

    @ti.func
    def sample(self, x):
        o = ti.Vector(self.origin, dt=self.dtype)
        g = (x - o) * self.inv_h
        phi = ti.cast(FAR, self.dtype)
        n = ti.Vector([0.0, 0.0, 1.0], dt=self.dtype)
        inside = True
        for d in ti.static(range(3)):
            if g[d] < 0 or g[d] > self.shape[d] - 1:
                inside = False
        if inside:
            base = ti.Vector([0, 0, 0])
            f = g * 0.0
            for d in ti.static(range(3)):
                base[d] = ti.min(ti.cast(ti.floor(g[d]), ti.i32), self.shape[d] - 2)
                f[d] = g[d] - base[d]
            phi = 0.0
            grad = g * 0.0
            for a, b, c in ti.static(_CORNERS):
                v = self.phi[base[0] + a, base[1] + b, base[2] + c]
                wx = a * f[0] + (1 - a) * (1.0 - f[0])
                wy = b * f[1] + (1 - b) * (1.0 - f[1])
                wz = c * f[2] + (1 - c) * (1.0 - f[2])
                sx, sy, sz = ti.static(2 * a - 1, 2 * b - 1, 2 * c - 1)
                phi += v * wx * wy * wz
                grad += v * ti.Vector([sx * wy * wz, sy * wx * wz, sz * wx * wy], dt=self.dtype)
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

    def __init__(self, specs: list, n: int, dtype: Any, v: Any, gravity: float) -> None:
        self.es = tuple(float(s.restitution) for s in specs)
        self.any = any(e > 0 for e in self.es)
        self.v = v
        self.gravity = float(gravity)
        if self.any:
            self.e = ti.field(dtype, shape=n)
            self.vn = ti.field(dtype, shape=n)
            self.nrm = ti.Vector.field(3, dtype, shape=n)
            self.vw = ti.Vector.field(3, dtype, shape=n)

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
