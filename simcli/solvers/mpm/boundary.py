"""Grid boundary conditions of the MPM solver: domain walls and static colliders.

Both act on grid node velocities in ``grid_update`` (after gravity), the usual MPM way:

* colliders: a node inside an obstacle (signed distance < 0) gets the obstacle's contact
  condition (slip / sticky / separate, Coulomb friction) along the SDF normal; a frictionless slip or
  separate obstacle of an analytic shape also mirrors the material onto the free nodes less than 1.5
  cells in front of it (its image, ``_image``: the symmetry condition of a slip wall), so that a
  liquid at rest meets the surface with its bulk pressure instead of standing a cell off it; the image
  and the contact of the nodes inside such a collider fade out as the gap between the surface and the
  material the nodes gather grows (``_fade``: no force across a gap, a dropped floating body does not
  ride on a sparse layer);
  a frictional static one of an analytic shape acts on a node inside it only once the node's material
  has reached the surface (its gap test, ``gap_test``), not up to 1.5 cells before it touches, and
  (under APIC) on the velocity of that material rather than the node's extrapolation of it;
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
    ColliderPoses,
    collider_motions,
    collider_specs,
    contact_velocity,
    project_out,
    project_out_e,
    sdf_box,
    sdf_cylinder,
    sdf_plane,
    sdf_sphere,
    wall_specs,
)
from simcli.solvers.mpm.cpic import cpic_indices

with stdout_to_stderr():
    import taichi as ti


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
        self.colliders = collider_specs(scene, dim, scene_dir)
        self.walls = wall_specs(scene, dim)
        self.n_colliders = len(self.colliders)
        # CPIC colliders (cpic.py) have no image (its mirror point lies across a thin plate) and their
        # contact condition also acts on the nodes up to CPIC_REACH cells in front of them
        self.cpic = frozenset(cpic_indices(scene))  # colliders and rigid bodies with cpic: true
        # moving and named colliders: poses uploaded per substep, loads summed (compiled only if any)
        self.poses = ColliderPoses(self.colliders, collider_motions(scene, dim, scene_dir), dim, dtype)
        self.any_moving, self.any_named, self.named = (
            self.poses.any_moving,
            self.poses.any_named,
            self.poses.named,
        )
        # the nodes' material position (a P2G channel): the frictional gap test and the image's fade
        self.uses_gap_test = any(self.gap_test(k) for k in range(self.n_colliders))
        self.uses_gap = self.uses_gap_test or any(self.has_image(k) for k in range(self.n_colliders))
        # the gap test's contact acts on the material's velocity (``_node``): set by the solver when P2G
        # gathers the nodes' APIC affine momentum (not under FLIP, whose nodes carry none)
        self.material_velocity = False

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
        self.upload()
        self.poses.allocate()
        if any(c.kind == "Mesh" for c in self.colliders):  # signed-distance grids (simcli.collider_mesh)
            from simcli.collider_mesh_kernels import mesh_fields

            self.mesh_fields = mesh_fields(self.colliders, f, normal_below=0.0)  # normals used inside only
            # squared reach of each Mesh from its pivot (+ a cell): beyond it a point is outside the mesh
            piv = self.poses.pivot.to_numpy() if self.poses.needed else np.zeros((self.n_colliders, dim))
            self.mesh_reach2 = tuple(  # (2D polygon bodies: their image's 1.5 dx in front too)
                (float(np.linalg.norm(c.mesh.vertices - piv[k], axis=1).max()) + self._mesh_margin(k)) ** 2
                if c.kind == "Mesh"
                else 0.0
                for k, c in enumerate(self.colliders)
            )

    # the image's fade (``_fade``) with the gap between the surface and the material [cells]: full below
    # FADE_START (the gap estimate's bias and noise with particles in contact, a few hundredths of a
    # cell), none from FADE_END (0.3 particle spacing at 2 particles per cell). Measured (issue 20,
    # docs/RIGID.md): 0.1-0.25 left the dropped rho-250 box 12.5% high, 0-0.1 let the rho-500 one sink
    # 5% deep and the held box at 0.02 m read -4.1%; 0.05-0.15 gives -8.7/+2.8/-0.9% and +0.3%.
    FADE_START = 0.05
    # a CPIC collider's (cpic.py) contact condition acts on the nodes less than this [cells] in front of it
    CPIC_REACH = 0.5
    FADE_END = 0.15

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

    def set_time(self, t: float, dt: float) -> None:
        self.poses.set_time(t, dt)

    def take_loads(self) -> np.ndarray:
        return self.poses.take_loads()

    @ti.func
    def sdf_at(self, k: ti.template(), x, slot):
        """(phi, outward normal, surface velocity) of collider k at world point x: a moving collider's
        signed distance is its body-frame one at R^T (x - c) + p, its normal turned by R."""
        phi = 1.0
        n = x * 0.0
        vw = x * 0.0
        if ti.static(self.colliders[k].moving and self.colliders[k].kind == "Mesh"):
            # a moving Mesh: points beyond its reach from the moving pivot are outside it (no pose
            # transform, no grid lookup): most nodes and particles of a scene
            d2 = 0.0
            for i in ti.static(range(self.dim)):
                d2 += (x[i] - self.poses.pose[slot, k, 9 + i]) ** 2
            if d2 < self.mesh_reach2[k]:
                phi, nb = self.sdf(k, self.poses.to_body(k, x, slot))
                # (the normal and the surface velocity are used inside only; a 2D polygon's image in front)
                if phi < ti.static(self.reach(k) if self.has_image(k) else 0.0):
                    n = self.poses.normal_to_world(k, nb, slot)
                    vw = self.poses.velocity(k, x, slot)
        elif ti.static(self.colliders[k].moving):
            phi, nb = self.sdf(k, self.poses.to_body(k, x, slot))
            n = self.poses.normal_to_world(k, nb, slot)
            vw = self.poses.velocity(k, x, slot)
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
        elif ti.static(self.colliders[k].kind == "Mesh"):
            phi, n = self.mesh_fields[k].sample(x)
        return phi, n

    @ti.func
    def _project(self, x, v, phi, n, k: ti.template()):
        """project_out, with restitution where the collider has some (compile-time)."""
        xo, vo = x, v
        if ti.static(self.colliders[k].restitution > 0):
            xo, vo = project_out_e(
                x, v, phi, n, self.colliders[k].contact, self.col_friction[k], self.colliders[k].restitution
            )
        else:
            xo, vo = project_out(x, v, phi, n, self.colliders[k].contact, self.col_friction[k])
        return xo, vo

    @ti.func
    def project_particle(self, x, v, mp):
        """Particle-level contact after advection: out of every collider, inward velocity removed
        (see :func:`simcli.colliders.project_out`); a named collider takes the momentum removed from the
        particle (mass ``mp``). Compiled only when colliders exist."""
        for k in ti.static(range(self.n_colliders)):
            if ti.static(k in self.cpic and self.colliders[k].kind == "Box"):
                pass  # a thin CPIC Box: cpic.CPIC.keep_side, onto the face of the particle's side
            elif ti.static(self.colliders[k].kind == "Mesh" and (self.colliders[k].moving or self.named[k])):
                phi, n, vw = self.sdf_at(k, x, 1)
                if phi < 0:  # (only then: a particle away from it keeps its velocity bit for bit)
                    x_new, vr = self._project(x, v - vw, phi, n, k)
                    if ti.static(self.named[k]):
                        self.poses.add_load(k, x_new, mp * (v - (vr + vw)), 1)
                    x, v = x_new, vr + vw
            elif ti.static(self.colliders[k].moving or self.named[k]):
                phi, n, vw = self.sdf_at(k, x, 1)
                x_new, vr = self._project(x, v - vw, phi, n, k)
                if ti.static(self.named[k]):
                    if phi < 0:
                        self.poses.add_load(k, x_new, mp * (v - (vr + vw)), 1)
                x, v = x_new, vr + vw
            else:
                phi, n = self.sdf(k, x)
                x, v = self._project(x, v, phi, n, k)
        return x, v

    def bind_grid(self, grid, bbox, T: int, gravity, gap_ch: int = -1) -> None:
        """The P2G grid copies, their node boxes, the gravity field and the first material position
        channel, read by the colliders' image (``_image``); called by grid_update.build_grid_update."""
        self._grid, self._bbox, self._T, self._gravity = grid, bbox, int(T), gravity
        self._gap_ch = int(gap_ch)
        self.grid_shape = tuple(int(s) for s in grid.shape[1:])

    def reach(self, k: int) -> float:
        """Nodes of collider k's condition: phi below this (inside it; with an image, 1.5 dx in front)."""
        if k in self.cpic:  # a thin CPIC plate: the nodes up to half a cell in front of it too (cpic.py)
            return self.CPIC_REACH * self.dx
        return 1.5 * self.dx if self.has_image(k) else 0.0

    def _mesh_margin(self, k: int) -> float:
        return (2.0 if self.has_image(k) else 1.0) * self.dx

    def has_image(self, k: int) -> bool:
        """Collider k mirrors the material near it onto the free nodes in front of it (``_image``): a
        frictionless slip or separate surface of an analytic shape (a Mesh's normals are sampled inside
        it only; a 2D Mesh body's polygon grid has them in front too, simcli.rigid.polygon). Not with
        friction: the band of image nodes, 1.5 dx in front of the surface, would brake material that is
        not in contact yet (a disk rolling down an incline, mpm_roll_incline, covered 0.057 m instead of
        0.148 m of 0.221 m), and without friction on it a sliding block loses its Coulomb friction (+40%
        distance); nor sticky."""
        c = self.colliders[k]
        analytic = c.kind != "Mesh" or self.dim == 2  # 2D: a polygon body's grid has its normals in front
        return analytic and c.contact != "sticky" and c.friction <= 0 and k not in self.cpic

    @ti.func
    def raw(self, J):
        """Momentum (after the substep's stress impulse) and mass of node J summed over the P2G copies
        (zero outside the grid and outside every copy's node box)."""
        return self._raw(J, 0, self.dim + 1)

    @ti.func
    def _raw(self, J, c0: ti.template(), nc: ti.template()):
        """Channels c0 .. c0 + nc - 1 of node J summed over the P2G copies (see ``raw``)."""
        g = ti.Vector.zero(self.dtype, nc)
        inb = True
        for d in ti.static(range(self.dim)):
            inb = inb and 0 <= J[d] and J[d] < self.grid_shape[d]
        if inb:
            # a run-time loop over the copies (and over the corners in ``interp``): unrolled, every
            # collider with an image inlined 2^dim x T copies of this, and compiling them took minutes
            for t in range(self._T):
                a = self._bbox[t, 0]
                b = self._bbox[t, 1]
                inside = True
                for d in ti.static(range(self.dim)):
                    inside = inside and a[d] <= J[d] and J[d] < b[d]
                if inside:
                    gt = self._grid[t, J]
                    for c in ti.static(range(nc)):
                        g[c] += gt[c0 + c]
        return g

    @ti.func
    def interp(self, x):
        """Raw grid momentum and mass (see ``raw``) at point x, multilinear between the nodes around it."""
        s = (x - ti.Vector(self.origin, dt=self.dtype)) / self.dx
        base = ti.floor(s).cast(ti.i32)
        fr = s - base.cast(self.dtype)
        src = ti.Vector.zero(self.dtype, self.dim + 1)
        # corner c has offset bit (dim - 1 - d) of c along axis d: the order of ti.ndrange(2, .., 2)
        # (last axis fastest), so the sum is the same as unrolled, one call site instead of 2^dim
        for c in range(2**self.dim):
            off = ti.Vector.zero(ti.i32, self.dim)
            w = 1.0
            for d in ti.static(range(self.dim)):
                if (c >> (self.dim - 1 - d)) & 1 == 1:
                    off[d] = 1
                    w *= fr[d]
                else:
                    w *= 1.0 - fr[d]
            src += w * self.raw(base + off)
        return src

    def gap_test(self, k: int) -> bool:
        """Collider k's contact condition acts on a node inside it only where the node's material (the
        mass-weighted position of the particles it gathers, a P2G channel) is no further from the surface
        than that of a flat body resting on it would be (``_rest_gap``): a frictional slip or separate
        surface of a static analytic shape. Without it, nodes under the plane take a rolling disk's
        normal velocity off up to 1.5 cells before its material touches (an inelastic hit at the front
        of the contact every substep: rolling resistance, 0.148 m of 0.221 m in mpm_roll_incline), the
        gap test as in Nairn's and Lemiale's multi-material contact. Frictionless surfaces have their
        image instead; moving and named colliders and Meshes keep the nodes-inside condition.

        Under APIC the condition (normal and Coulomb friction) acts on the velocity of the node's material
        at its position xm, the node's velocity less its affine part (sum w m C_p (x_i - x_p) / m, a P2G
        channel), and the node takes the same change. A node under the surface holds the material's
        velocity extrapolated to its depth: for a rolling disk, backwards by omega times the depth, so
        sticking the node (tangential velocity 0) left the material at the surface slipping forwards
        (mpm_roll_incline: R theta 6-11% short of the travel, the same at friction 2.0; now within 2-3%)."""
        c = self.colliders[k]
        return (
            c.kind != "Mesh"
            and c.contact != "sticky"
            and c.friction > 0
            and not c.moving
            and not self.named[k]
        )

    @ti.func
    def _rest_gap(self, phi):
        """Distance from the surface [m] of the material gathered by a node at signed distance ``phi`` < 0
        (quadratic B-spline weights) when a flat body fills the half-space in front of the surface: with
        d = -phi / dx in [0, 1.5], (1.5 - d) / 4 dx for d >= 1/2, a quadratic fit (error < 1e-4 dx) below."""
        d = ti.min(ti.max(-phi / self.dx, 0.0), 1.5)
        y = (1.5 - d) / 4.0
        if d < 0.5:
            y = 0.4063 - 0.3890 * d + 0.1528 * d * d
        return y * self.dx

    @ti.func
    def _phi(self, k: ti.template(), x):
        """Signed distance of x from collider k (at the substep's mid pose if it moves)."""
        phi = 1.0
        if ti.static(self.colliders[k].moving or self.named[k]):
            phi, _n, _vw = self.sdf_at(k, x, 0)
        else:
            phi, _n = self.sdf(k, x)
        return phi

    @ti.func
    def _contact_dist(self, phi):
        """Distance from the surface [m] of the material gathered by a node at signed distance ``phi``
        (quadratic B-spline weights) when the material fills the half-space in front of the surface up to
        it: phi + T1(a) / M with a = |phi| / dx, T0(a) and T1(a) the kernel's tail integrals of 1 and u
        beyond a, M = T0 inside (phi < 0) and 1 - T0 in front (exact; e.g. 0.406 dx on the surface)."""
        a = ti.min(ti.abs(phi) / self.dx, 1.5)
        t0 = 0.0
        t1 = 0.0
        if a < 0.5:
            t0 = 0.75 * (0.5 - a) - (0.125 - a * a * a) / 3.0 + 1.0 / 6.0
            t1 = 0.375 * (0.25 - a * a) - (0.0625 - a * a * a * a) / 4.0 + 0.125
        else:
            b = 1.5 - a
            t0 = b * b * b / 6.0
            t1 = 0.25 * b * b * b - 0.125 * b * b * b * b
        mm = t0
        if phi >= 0:
            mm = 1.0 - t0
        r = phi
        if mm > 1e-6:
            r = phi + t1 / mm * self.dx
        return r

    @ti.func
    def _fade(self, gap):
        """Weight of a frictionless collider's condition (its image, and the contact of the nodes inside
        it) for a material ``gap`` [m] between the surface and the material nodes gather (their material
        position beyond where material in contact would put it, ``_contact_dist``): 1 up to FADE_START dx,
        0 from FADE_END dx, linear between."""
        g0 = ti.static(self.FADE_START * self.dx)
        g1 = ti.static(self.FADE_END * self.dx)
        return ti.min(ti.max((g1 - gap) / (g1 - g0), 0.0), 1.0)

    @ti.func
    def _mirror_gap(self, k: ti.template(), xs):
        """The gap [m] between collider k's surface and the material the nodes around the point xs
        gather (multilinear weights times node mass): their material position's distance from the surface
        less ``_contact_dist`` of each node, mass-weighted; 0 without material."""
        dim = ti.static(self.dim)
        s = (xs - ti.Vector(self.origin, dt=self.dtype)) / self.dx
        base = ti.floor(s).cast(ti.i32)
        fr = s - base.cast(self.dtype)
        num = 0.0
        den = 0.0
        # a run-time loop over the corners, in ti.ndrange(2, .., 2)'s order (as ``interp``): unrolled, each
        # corner inlined two signed distances of the collider (a moving Box body's pose transforms), and the
        # MPM substep of a scene with one Box body took 208 s to compile
        for c in range(2**dim):
            off = ti.Vector.zero(ti.i32, dim)
            w = 1.0
            for d in ti.static(range(dim)):
                if (c >> (dim - 1 - d)) & 1 == 1:
                    off[d] = 1
                    w *= fr[d]
                else:
                    w *= 1.0 - fr[d]
            J = base + off
            mJ = self._raw(J, dim, 1)[0]
            if mJ > 0 and w > 0:
                xJ = ti.Vector(self.origin, dt=self.dtype) + J.cast(self.dtype) * self.dx
                xm = self._raw(J, self._gap_ch, dim) / mJ
                num += w * mJ * (self._phi(k, xm) - self._contact_dist(self._phi(k, xJ)))
                den += w * mJ
        gap = 0.0
        if den > 0:
            gap = num / den
        return gap

    @ti.func
    def _image(self, k: ti.template(), xI, v, m, phi, n, vw, dt, bilateral: ti.template()):
        """Velocity of a free node in front of a collider (0 <= phi < 1.5 dx) after the collider's
        mirror image of the material: the grid's momentum and mass at the node's mirror point
        x - 2 phi n (interpolated between the nodes around it, before any condition), reflected about
        the surface (the normal part of its momentum relative to the surface reversed, its gravity
        too), are added to the node's, and the node keeps the normal part of the change (tangential
        velocity untouched: a frictionless surface); only a push away from the surface unless the
        contact is ``slip`` (bilateral, as on the nodes inside).

        This is a slip wall's symmetry condition. Without it the first free nodes' kernels reach past
        the surface into nodes that no material fills, the material's stress is not carried there as in
        the bulk and a liquid at rest stands a cell off the surface: the force on a wall, on a floating
        body, reads the pressure of a shallower depth (first order in dx).

        The change is faded (``_fade``) with the gap between the surface and the material the nodes
        around the mirror point gather (``_mirror_gap``): mirrored mass reaches the node from material
        up to 1.5 cells from the surface, so without the fade the image carried a body across a sub-cell
        gap (a dropped box rested on a sparse layer of liquid and floated 23% high, docs/RIGID.md)."""
        dim = ti.static(self.dim)
        xs = xI - 2.0 * phi * n
        src = self.interp(xs)
        ms = src[dim]
        v_new = v
        if ms > 0:
            fade = self._fade(self._mirror_gap(k, xs))
            P = ti.Vector.zero(self.dtype, dim)
            for d in ti.static(range(dim)):
                P[d] = src[d]
            P += ms * (dt * self._gravity[None] - vw)  # the image's momentum relative to the surface
            P = P - 2.0 * P.dot(n) * n + ms * vw  # reflected
            dn = fade * ((m * v + P) / (m + ms) - v).dot(n)
            if ti.static(bilateral):
                v_new = v + dn * n
            elif dn > 0:
                v_new = v + dn * n
        return v_new

    def thin_axis(self, k: int) -> int:
        """A Box's thinnest axis (a CPIC plate's normal in its body frame)."""
        c = self.colliders[k]
        return int(np.argmin(np.asarray(c.b, float) - np.asarray(c.a, float)))

    @ti.func
    def _cpic_face(self, k: ti.template(), n):
        """Is the normal n along CPIC collider k's thin axis (a broad face of a plate, not its edge; a
        Plane: always)? Its edges get no band: a node band ahead of a moving edge pushed the material ahead
        (a blade edge-first through sand heaved the cover by 4 cells' worth)."""
        r = True
        if ti.static(self.colliders[k].kind == "Box"):
            nt = ti.Vector.unit(self.dim, ti.static(self.thin_axis(k)), self.dtype)
            if ti.static(self.colliders[k].moving or self.named[k]):
                nt = self.poses.normal_to_world(k, nt, 0)
            r = ti.abs(n.dot(nt)) > 0.99
        return r

    @ti.func
    def _node(self, k: ti.template(), xI, v, m, phi, n, vw, dt, xm, va):
        """Collider k's condition on a node at signed distance phi (below ``reach(k)``): inside it, the
        contact condition (simcli.colliders.contact_velocity; with the gap test, ``gap_test``, only once
        the node's material at ``xm`` has reached the surface, and on that material's velocity
        ``v - va``: ``material_velocity``; with an image, faded with the gap of the node's material,
        ``_fade``); in front of it, its image (``_image``)."""
        touching = True
        if ti.static(self.gap_test(k)):
            if phi < 0:
                phm, _nm = self.sdf(k, xm)
                touching = phm <= self._rest_gap(phi)
        in_band = False  # a thin CPIC plate: the nodes up to CPIC_REACH in front of its broad faces too
        if ti.static(k in self.cpic):
            in_band = self._cpic_face(k, n)
        if (phi < 0 or in_band) and touching:
            if ti.static(self.gap_test(k) and self.material_velocity):
                vs = v - va  # the material's velocity at xm: the node's less its APIC extrapolation
                v = v + (contact_velocity(vs, n, vw, self.colliders[k].contact, self.col_friction[k]) - vs)
            elif ti.static(
                self.has_image(k)
            ):  # faded as the image: only where the material is at the surface
                vc = contact_velocity(v, n, vw, self.colliders[k].contact, self.col_friction[k])
                v = v + self._fade(self._phi(k, xm) - self._contact_dist(phi)) * (vc - v)
            else:
                v = contact_velocity(v, n, vw, self.colliders[k].contact, self.col_friction[k])
        elif ti.static(self.has_image(k)):
            v = self._image(k, xI, v, m, phi, n, vw, dt, ti.static(self.colliders[k].contact == "slip"))
        return v

    @ti.func
    def apply(self, I, v, m, dt, xm, va):
        """Velocity of grid node ``I`` (mass ``m``, its material's position ``xm``: the gap test) after
        every collider and wall condition. A named collider takes the opposite of the momentum its
        condition gave the node (and its moment)."""
        if ti.static(self.n_colliders > 0):
            xI = ti.Vector(self.origin, dt=self.dtype) + I.cast(self.dtype) * self.dx
            for k in ti.static(range(self.n_colliders)):
                if ti.static(not self.colliders[k].moving and not self.named[k]):
                    phi, n = self.sdf(k, xI)
                    if phi < ti.static(self.reach(k)):
                        v = self._node(k, xI, v, m, phi, n, v * 0.0, dt, xm, va)
                else:
                    phi, n, vw = self.sdf_at(k, xI, 0)
                    if phi < ti.static(self.reach(k)):
                        v_new = self._node(k, xI, v, m, phi, n, vw, dt, xm, va)
                        if ti.static(self.named[k]):  # the impulse the node gives the collider [N s]
                            self.poses.add_load(k, xI, m * (v - v_new), 0)
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
