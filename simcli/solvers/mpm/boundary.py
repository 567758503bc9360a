"""Grid boundary conditions of the MPM solver: domain walls and static colliders.

Both act on grid node velocities in ``grid_update`` (after gravity), the usual MPM way:

* colliders: a node inside an obstacle (signed distance < 0) gets the obstacle's contact
  condition (slip / sticky / separate, Coulomb friction) along the SDF normal;
* walls: every node on or beyond a face of the domain box gets that face's condition, with the
  face normal pointing into the domain. The grid extends ``pad`` cells beyond the domain, so
  this is a band of nodes (the face node plus the padding ones) and particles, which are also
  clamped to the box, never leave the domain.

Colliders also act on particles after g2p's advection (``project_particle``): a particle found
inside one (it started there, or a fast one tunnelled through the grid contact) is moved back to
the surface along the SDF normal and loses its inward normal velocity.

What is compiled: one code path per collider present (its kind, contact kind and cylinder
axis) and per face (its contact kind). What is data: collider geometry, friction coefficients
and wall velocities (fields, changeable between substeps without recompiling).
"""

from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.colliders import (
    collider_motions,
    collider_specs,
    contact_velocity,
    project_out,
    sdf_box,
    sdf_cylinder,
    sdf_plane,
    sdf_sphere,
    wall_specs,
)

with stdout_to_stderr():
    import taichi as ti

POSE_LEN = 18  # R (9, row-major dim x dim), c (3), v (3), w (3)


@ti.data_oriented
class GridBoundary:
    """Walls of the domain box + colliders, applied to grid nodes.

    ``origin``/``dx``: node I sits at origin + I dx. ``lo_node``/``hi_node``: index of the first
    and last node of the domain along each axis (nodes at or beyond them are wall nodes).
    """

    def __init__(
        self,
        scene: Any,
        dim: int,
        dtype: Any,
        origin: np.ndarray,
        dx: float,
        lo_node: tuple,
        hi_node: tuple,
        scene_dir: Any = None,
    ) -> None:
        self.dim = dim
        self.dtype = dtype
        self.origin = tuple(float(o) for o in origin)
        self.dx = float(dx)
        self.lo_node = tuple(int(i) for i in lo_node)
        self.hi_node = tuple(int(i) for i in hi_node)
        self.colliders = collider_specs(scene, dim)
        self.walls = wall_specs(scene, dim)
        self.n_colliders = len(self.colliders)
        self.motions = collider_motions(scene, dim, scene_dir)
        # compile-time: any moving collider (poses uploaded per substep), any named one (loads summed)
        self.any_moving = any(c.moving for c in self.colliders)
        self.named = tuple(c.name is not None for c in self.colliders)
        self.any_named = any(self.named)
        self.posed = self.any_moving or self.any_named

    def allocate(self) -> None:
        dim, f = self.dim, self.dtype
        nw = len(self.walls)
        self.wall_velocity = ti.Vector.field(dim, f, shape=nw)
        self.wall_friction = ti.field(f, shape=nw)
        nc = max(1, self.n_colliders)
        self.col_a = ti.Vector.field(dim, f, shape=nc)
        self.col_b = ti.Vector.field(dim, f, shape=nc)
        self.col_radius = ti.field(f, shape=nc)
        self.col_half_height = ti.field(f, shape=nc)
        self.col_friction = ti.field(f, shape=nc)
        if self.posed:
            # per collider and slot (0: the middle of the substep, for grid nodes; 1: its end, for
            # particles): R (dim x dim), moving pivot c (dim), velocity v (dim), angular velocity w (3)
            self.pose = ti.field(f, shape=(2, nc, POSE_LEN))
            self.col_pivot = ti.Vector.field(dim, f, shape=nc)
            # load on each named collider summed since the last read: -(impulse on the material) [N s]
            # and its moment about the moving pivot [N m s] (3 components; z alone in 2D)
            self.load = ti.field(ti.f64, shape=(nc, dim + 3))
        self.upload()

    def upload(self) -> None:
        """Copy the run-time numbers (geometry, friction, wall velocity) into the fields."""
        npf = np.float64 if self.dtype == ti.f64 else np.float32
        self.wall_velocity.from_numpy(np.array([w.velocity for w in self.walls], dtype=npf))
        self.wall_friction.from_numpy(np.array([w.friction for w in self.walls], dtype=npf))
        nc = max(1, self.n_colliders)
        a = np.zeros((nc, self.dim), npf)
        b = np.zeros((nc, self.dim), npf)
        r = np.zeros(nc, npf)
        h = np.zeros(nc, npf)
        mu = np.zeros(nc, npf)
        for k, c in enumerate(self.colliders):
            a[k], b[k], r[k], h[k], mu[k] = c.a, c.b, c.radius, c.half_height, c.friction
        self.col_a.from_numpy(a)
        self.col_b.from_numpy(b)
        self.col_radius.from_numpy(r)
        self.col_half_height.from_numpy(h)
        self.col_friction.from_numpy(mu)
        if self.posed:
            piv = np.zeros((nc, self.dim), npf)
            for k, c in enumerate(self.colliders):
                if c.centre:
                    m = self.motions[k]
                    piv[k] = m.pivot[: self.dim] if m is not None else c.centre
            self.col_pivot.from_numpy(piv)
            self.load.fill(0.0)
            self.set_time(0.0, 0.0)

    def set_time(self, t: float, dt: float) -> None:
        """Upload every collider's pose for the substep [t, t + dt] (host -> one small copy; no compile)."""
        if not self.posed:
            return
        npf = np.float64 if self.dtype == ti.f64 else np.float32
        d = self.dim
        nc = max(1, self.n_colliders)
        buf = np.zeros((2, nc, POSE_LEN), npf)
        for k, c in enumerate(self.colliders):
            m = self.motions[k]
            for slot, ts in enumerate((t + 0.5 * dt, t + dt)):
                if m is None:
                    R, cen, v, w = np.eye(d), np.asarray(c.centre or (0.0,) * d), np.zeros(d), np.zeros(3)
                else:
                    ps = m.pose(ts)
                    R, cen, v, w = ps.R, ps.c, ps.v, ps.w
                buf[slot, k, : d * d] = R.reshape(-1)
                buf[slot, k, 9 : 9 + d] = cen
                buf[slot, k, 12 : 12 + d] = v
                buf[slot, k, 15:18] = w
        self.pose.from_numpy(buf)

    def take_loads(self) -> np.ndarray:
        """(n_colliders, dim + 3) impulse and angular impulse summed since the last call; resets them."""
        if not self.posed:
            return np.zeros((self.n_colliders, self.dim + 3))
        a = self.load.to_numpy()[: self.n_colliders]
        self.load.fill(0.0)
        return a

    @ti.func
    def _pose(self, slot, k: ti.template()):
        d = ti.static(self.dim)
        R = ti.Matrix.zero(self.dtype, d, d)
        c = ti.Vector.zero(self.dtype, d)
        v = ti.Vector.zero(self.dtype, d)
        w = ti.Vector.zero(self.dtype, 3)
        for i in ti.static(range(d)):
            for j in ti.static(range(d)):
                R[i, j] = self.pose[slot, k, i * d + j]
            c[i] = self.pose[slot, k, 9 + i]
            v[i] = self.pose[slot, k, 12 + i]
        for i in ti.static(range(3)):
            w[i] = self.pose[slot, k, 15 + i]
        return R, c, v, w

    @ti.func
    def _cross(self, w, r):
        """w x r for w (3,) and r (dim,): a dim vector (2D: about z)."""
        out = r * 0.0
        if ti.static(self.dim == 2):
            out = ti.Vector([-w[2] * r[1], w[2] * r[0]])
        else:
            out = w.cross(r)
        return out

    @ti.func
    def _moment(self, r, f):
        """r x f as 3 components (2D: only z)."""
        out = ti.Vector.zero(self.dtype, 3)
        if ti.static(self.dim == 2):
            out[2] = r[0] * f[1] - r[1] * f[0]
        else:
            out = r.cross(f)
        return out

    @ti.func
    def sdf_at(self, k: ti.template(), x, slot):
        """(phi, outward normal, surface velocity) of collider k at world point x: a moving collider's
        signed distance is its body-frame one at R^T (x - c) + p, its normal turned by R."""
        phi = 1.0
        n = x * 0.0
        vw = x * 0.0
        if ti.static(self.colliders[k].moving):
            R, c, v, w = self._pose(slot, k)
            xb = R.transpose() @ (x - c) + self.col_pivot[k]
            phi, nb = self.sdf(k, xb)
            n = R @ nb
            vw = v + self._cross(w, x - c)
        else:
            phi, n = self.sdf(k, x)
        return phi, n, vw

    @ti.func
    def sdf(self, k: ti.template(), x):
        """(phi, outward normal) of collider k at x."""
        phi = 1.0
        n = x * 0.0
        if ti.static(self.colliders[k].kind == "Plane"):
            phi, n = sdf_plane(x, self.col_a[k], self.col_b[k])
        elif ti.static(self.colliders[k].kind == "Sphere"):
            phi, n = sdf_sphere(x, self.col_a[k], self.col_radius[k])
        elif ti.static(self.colliders[k].kind == "Box"):
            phi, n = sdf_box(x, self.col_a[k], self.col_b[k])
        elif ti.static(self.colliders[k].kind == "Cylinder"):
            phi, n = sdf_cylinder(
                x, self.col_a[k], self.col_radius[k], self.col_half_height[k], self.colliders[k].axis
            )
        return phi, n

    @ti.func
    def project_particle(self, x, v):
        """Particle-level contact after advection: out of every collider, inward velocity removed
        (see :func:`simcli.colliders.project_out`). Compiled only when colliders exist."""
        for k in ti.static(range(self.n_colliders)):
            if ti.static(self.colliders[k].moving):
                phi, n, vw = self.sdf_at(k, x, 1)
                x, vr = project_out(x, v - vw, phi, n, self.colliders[k].contact, self.col_friction[k])
                v = vr + vw
            else:
                phi, n = self.sdf(k, x)
                x, v = project_out(x, v, phi, n, self.colliders[k].contact, self.col_friction[k])
        return x, v

    @ti.func
    def apply(self, I, v, m):
        """Velocity of grid node ``I`` (mass ``m``) after every collider and wall condition. A named
        collider takes the opposite of the momentum its condition gave the node (and its moment)."""
        if ti.static(self.n_colliders > 0):
            xI = ti.Vector(self.origin, dt=self.dtype) + I.cast(self.dtype) * self.dx
            for k in ti.static(range(self.n_colliders)):
                if ti.static(not self.colliders[k].moving and not self.named[k]):
                    phi, n = self.sdf(k, xI)
                    if phi < 0:
                        v = contact_velocity(v, n, v * 0.0, self.colliders[k].contact, self.col_friction[k])
                else:
                    phi, n, vw = self.sdf_at(k, xI, 0)
                    if phi < 0:
                        v_new = contact_velocity(v, n, vw, self.colliders[k].contact, self.col_friction[k])
                        if ti.static(self.named[k]):
                            _R, c, _v, _w = self._pose(0, k)
                            J = m * (v - v_new)  # impulse the node gives the collider [N s]
                            M = self._moment(xI - c, J)
                            for i in ti.static(range(self.dim)):
                                ti.atomic_add(self.load[k, i], ti.cast(J[i], ti.f64))
                            for i in ti.static(range(3)):
                                ti.atomic_add(self.load[k, self.dim + i], ti.cast(M[i], ti.f64))
                        v = v_new
        # walls last: confinement to the domain wins over everything else
        for k in ti.static(range(len(self.walls))):
            on_wall = False
            if ti.static(self.walls[k].side < 0):
                on_wall = I[self.walls[k].axis] <= self.lo_node[self.walls[k].axis]
            else:
                on_wall = I[self.walls[k].axis] >= self.hi_node[self.walls[k].axis]
            if on_wall:
                n = ti.Vector.unit(self.dim, self.walls[k].axis, self.dtype) * (-self.walls[k].side)
                v = contact_velocity(
                    v, n, self.wall_velocity[k], self.walls[k].contact, self.wall_friction[k]
                )
        return v
