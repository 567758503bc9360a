"""Static rigid obstacles and domain walls as velocity conditions, shared by the solvers.

Two halves, like the materials:

* host side (no Taichi): :func:`collider_specs` and :func:`wall_specs` turn the scene into
  small records. What decides which code is compiled (collider kind, contact kind, cylinder
  axis, wall kind per face) is kept apart from the numbers (points, radii, friction, wall
  velocity), which live in fields and can change without recompiling; :func:`sdf_np` and
  :func:`inside_normal_np` are the numpy half of the signed distance (the same formulas and ties as the
  Taichi ``sdf_*``), used on the host by SPH (sampling, push-out at build), SF (solid cells) and verify:
  one collider geometry for every family;
* kernel side: signed-distance functions ``sdf_*`` returning ``(phi, normal)`` with ``phi < 0``
  inside the obstacle and ``normal`` the unit outward normal, :func:`contact_velocity`, the
  slip / sticky / separate condition with Coulomb friction (grid nodes), and
  :func:`project_out`, which moves a particle found inside an obstacle back to its surface.

Importing this module imports Taichi (with stdout kept clean) but does not initialise it.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.collider_spec import ColliderSpec  # noqa: F401 (the record every family reads)

with stdout_to_stderr():
    import taichi as ti

CONTACT_KINDS = ("slip", "sticky", "separate")
FACE_NAMES = ("x-", "x+", "y-", "y+", "z-", "z+")


@dataclass(frozen=True)
class WallSpec:
    """One face of the domain box: ``axis``, ``side`` (-1 lower, +1 upper), compile-time ``contact``."""

    name: str
    axis: int
    side: int
    contact: str
    friction: float
    velocity: tuple  # wall velocity [m/s]


def collider_specs(scene: Any, dim: int, scene_dir: Any = None) -> list[ColliderSpec]:
    """``scene_dir``: Mesh colliders' files are relative to it."""
    specs = [_collider_spec_full(c, dim, scene, scene_dir) for c in scene.colliders]
    return specs + _rigid(scene, "specs", scene_dir)


def _collider_spec_full(c: Any, dim: int, scene: Any = None, scene_dir: Any = None) -> ColliderSpec:
    """One collider's record with its restitution, motion flag, name and pivot."""
    from dataclasses import replace

    from simcli.motion import collider_centre

    spec = _collider_spec(c, dim, scene, scene_dir)
    if getattr(c, "restitution", 0.0) > 0:
        spec = replace(spec, restitution=float(c.restitution))
    if getattr(c, "motion", None) is not None or getattr(c, "name", None) is not None:
        spec = replace(
            spec,
            moving=c.motion is not None,
            name=c.name,
            centre=tuple(float(x) for x in collider_centre(c, dim)),
        )
    return spec


def _rigid(scene: Any, what: str, scene_dir: Any = None) -> list:
    """Free rigid bodies (simcli.rigid) follow the colliders: moving, named colliders whose pose is
    integrated instead of prescribed (none without ``rigid_bodies``)."""
    if not getattr(scene, "rigid_bodies", None):
        return []
    from simcli.rigid.world import world_for

    w = world_for(scene, scene_dir)
    if w.collider_source is None:  # the scene's colliders, which the bodies meet (simcli.rigid.contact)
        n, dim = len(scene.colliders), int(scene.sim.dim)
        w.collider_source = lambda: zip(
            [_collider_spec_full(c, dim, scene, scene_dir) for c in scene.colliders[:n]],
            collider_motions(scene, dim, scene_dir)[:n],
        )
    return getattr(w, what)()


def collider_motions(scene: Any, dim: int, scene_dir: Any = None) -> list:
    """simcli.motion.Motion (or None) of every collider, in scene order."""
    from simcli.motion import collider_motion

    return [collider_motion(c, dim, scene_dir) for c in scene.colliders] + _rigid(scene, "motions", scene_dir)


def _collider_spec(c: Any, dim: int, scene: Any = None, scene_dir: Any = None) -> ColliderSpec:
    """The record of one collider model (its geometry in the body frame: its pose at t = 0)."""
    specs = []
    kind = c.type
    if kind == "Mesh":  # a signed-distance grid (simcli.collider_mesh)
        from simcli.collider_mesh import mesh_spec_numbers

        sdf, centre, half_diag = mesh_spec_numbers(c, dim, scene, scene_dir)
        return ColliderSpec(kind, c.boundary, 0, centre, (0.0,) * 3, half_diag, 0.0, c.friction, mesh=sdf)
    zeros = (0.0,) * dim
    if kind == "Plane":
        if len(c.point) != dim or len(c.normal) != dim:
            raise ValueError(f"Plane collider needs {dim} components for point and normal")
        n = np.asarray(c.normal, dtype=np.float64)
        norm = float(np.linalg.norm(n))
        if norm == 0.0:
            raise ValueError("Plane collider normal must not be zero")
        specs.append(ColliderSpec(kind, c.boundary, 0, tuple(c.point), tuple(n / norm), 0.0, 0.0, c.friction))
    elif kind == "Box":
        if len(c.lower) != dim or len(c.upper) != dim:
            raise ValueError(f"Box collider needs {dim} components for lower and upper")
        if any(lo >= hi for lo, hi in zip(c.lower, c.upper)):
            raise ValueError("Box collider: lower must be < upper on every axis")
        specs.append(ColliderSpec(kind, c.boundary, 0, tuple(c.lower), tuple(c.upper), 0.0, 0.0, c.friction))
    elif kind == "Sphere":
        if len(c.center) != dim:
            raise ValueError(f"Sphere collider needs {dim} components for center")
        specs.append(ColliderSpec(kind, c.boundary, 0, tuple(c.center), zeros, c.radius, 0.0, c.friction))
    elif kind == "Cylinder":
        if dim != 3:
            raise ValueError("Cylinder colliders exist only in 3D (use a Sphere, i.e. a disk, in 2D)")
        if len(c.center) != 3:
            raise ValueError("Cylinder collider needs 3 components for center")
        specs.append(
            ColliderSpec(
                kind,
                c.boundary,
                "xyz".index(c.axis),
                tuple(c.center),
                zeros,
                c.radius,
                0.5 * c.height,
                c.friction,
            )
        )
    else:  # pragma: no cover - the scene schema rejects unknown kinds
        raise ValueError(f"unknown collider type {kind!r}")
    return specs[0]


def wall_specs(scene: Any, dim: int) -> list[WallSpec]:
    walls = []
    for axis in range(dim):
        for side, sign in ((-1, "-"), (1, "+")):
            name = "xyz"[axis] + sign
            b = scene.domain.face(name)
            vel = tuple(b.velocity) if b.velocity is not None else (0.0,) * dim
            if len(vel) != dim:
                raise ValueError(f"domain face {name}: velocity needs {dim} components")
            walls.append(WallSpec(name, axis, side, b.type, b.friction, vel))
    return walls


# ----------------------------------------------------------------- kernel side


@ti.func
def _tangential(v, n, vn, mu):
    """Tangential part of ``v`` after Coulomb friction: |v_t| shrinks by mu*|v_n| (compressive v_n only)."""
    vt = v - vn * n
    if vn < 0 and mu > 0:
        vt_norm = vt.norm()
        if vt_norm > 0:
            vt *= ti.max(0.0, 1.0 + mu * vn / vt_norm)
    return vt


@ti.func
def contact_velocity(v, n, v_wall, contact: ti.template(), mu):
    """Velocity of a node in contact with a surface of unit normal ``n`` moving with ``v_wall``.

    slip: the normal relative velocity is removed both ways (the body cannot leave nor enter);
    separate: removed only when moving into the surface; sticky: the node moves with the surface.
    Friction (Coulomb, ``mu``) acts on the tangential relative velocity in proportion to the
    removed compressive normal velocity: the node's tangential velocity change is at most mu
    times its own normal velocity change (impulses per unit node mass, gravity of the substep
    included), so the friction impulse summed over the nodes is mu times the normal force.

    A frictional slip face (``mu > 0``) is unilateral like ``separate``: a node leaving it is
    released. Holding such a node (a tensile normal impulse, with no friction since there is no
    compression) while its neighbours' compressive impulses grow to balance it breaks Coulomb's
    law: a sliding block rocks on its front edge, its compressive nodes carry up to 5x its weight
    and it stops in 0.64 of Coulomb's distance (docs/VALIDATION.md, "Coulomb friction"). Without
    friction slip stays bilateral, as before.
    """
    vr = v - v_wall
    vn = vr.dot(n)
    if ti.static(contact == "sticky"):
        vr = vr * 0.0
    elif ti.static(contact == "slip"):
        if vn < 0 or mu <= 0:
            vr = _tangential(vr, n, vn, mu)
    else:  # separate
        if vn < 0:
            vr = _tangential(vr, n, vn, mu)
    return vr + v_wall


@ti.func
def project_out(x, v, phi, n, contact: ti.template(), mu):
    """Particle-level contact with a static obstacle: a particle at signed distance ``phi`` < 0
    moves to the surface along the unit outward normal ``n``; sticky: it stops; slip and
    separate: its velocity into the surface is removed (Coulomb friction ``mu`` on the
    tangential part in proportion). Velocities already leaving the surface are kept."""
    xo = x
    vo = v
    if phi < 0:
        xo = x - phi * n
        if ti.static(contact == "sticky"):
            vo = v * 0.0
        else:
            vn = v.dot(n)
            if vn < 0:
                vo = _tangential(v, n, vn, mu)
    return xo, vo


@ti.func
def project_out_e(x, v, phi, n, contact: ti.template(), mu, e):
    """:func:`project_out` with normal restitution ``e``: a particle moving into the surface leaves it with
    e times its normal speed (slip and separate). Compiled only for colliders with restitution > 0."""
    xo = x
    vo = v
    if phi < 0:
        xo = x - phi * n
        if ti.static(contact == "sticky"):
            vo = v * 0.0
        else:
            vn = v.dot(n)
            if vn < 0:
                vt = v - vn * n
                vtn = vt.norm()
                if vtn > 0 and mu > 0:
                    vt *= ti.max(0.0, 1.0 + mu * (1.0 + e) * vn / vtn)
                vo = vt - e * vn * n
    return xo, vo


@ti.func
def sdf_plane(x, point, normal):
    return (x - point).dot(normal), normal


@ti.func
def sdf_sphere(x, center, radius):
    d = x - center
    r = d.norm()
    n = d * 0.0
    n[n.n - 1] = 1.0
    if r > 0:
        n = d / r
    return r - radius, n


@ti.func
def sdf_box(x, lower, upper):
    c = 0.5 * (lower + upper)
    h = 0.5 * (upper - lower)
    d = x - c
    s = ti.math.sign(d)
    for i in ti.static(range(d.n)):
        if s[i] == 0:
            s[i] = 1.0
    q = ti.abs(d) - h
    qp = ti.max(q, 0.0)
    outside = qp.norm()
    phi = outside
    n = qp * s
    if outside > 0:
        n = n / outside
    else:
        # inside: the nearest face is the one with the largest q
        k = 0
        qmax = q[0]
        for i in ti.static(range(1, d.n)):
            if q[i] > qmax:
                qmax = q[i]
                k = i
        phi = qmax
        n = n * 0.0
        for i in ti.static(range(d.n)):
            if i == k:
                n[i] = s[i]
    return phi, n


@ti.func
def sdf_cylinder(x, center, radius, half_height, axis: ti.template()):
    """Capped cylinder along ``axis`` (3D)."""
    d = x - center
    a = d[axis]
    r = d
    r[axis] = 0.0
    rho = r.norm()
    rhat = r * 0.0
    if rho > 0:
        rhat = r / rho
    else:
        rhat[(axis + 1) % 3] = 1.0
    e = d * 0.0
    e[axis] = 1.0
    if a < 0:
        e[axis] = -1.0
    q0 = rho - radius
    q1 = ti.abs(a) - half_height
    p0 = ti.max(q0, 0.0)
    p1 = ti.max(q1, 0.0)
    outside = ti.sqrt(p0 * p0 + p1 * p1)
    phi = outside
    n = rhat
    if outside > 0:
        n = (p0 * rhat + p1 * e) / outside
    else:
        phi = ti.max(q0, q1)
        if q1 > q0:
            n = e
    return phi, n


# ---------------------------------------------------------- host side (numpy) signed distance


def sdf_np(spec: ColliderSpec, x: np.ndarray) -> np.ndarray:
    """Signed distance (negative inside) of a collider spec at points x (n, dim) [m]: the numpy half of
    the ``sdf_*`` Taichi functions above (the same formulas; a Mesh: its grid's trilinear phi, body frame)."""
    if spec.kind == "Mesh":
        return spec.mesh.sample(x)
    a = np.asarray(spec.a, dtype=np.float64)
    if spec.kind == "Plane":
        return (x - a) @ np.asarray(spec.b, dtype=np.float64)
    if spec.kind == "Sphere":
        return np.linalg.norm(x - a, axis=1) - spec.radius
    if spec.kind == "Box":
        b = np.asarray(spec.b, dtype=np.float64)
        c, half = 0.5 * (a + b), 0.5 * (b - a)
        q = np.abs(x - c) - half
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    if spec.kind == "Cylinder":
        r = x - a
        radial = np.linalg.norm(np.delete(r, spec.axis, axis=1), axis=1) - spec.radius
        along = np.abs(r[:, spec.axis]) - spec.half_height
        q = np.stack([radial, along], axis=1)
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    raise ValueError(spec.kind)


def inside_normal_np(spec: ColliderSpec, x: np.ndarray) -> np.ndarray:
    """The push-out direction of points inside a collider, as the ``sdf_*`` Taichi functions above choose
    it (ties included), so that the host can tell where a push-out sends a particle."""
    if spec.kind == "Mesh":  # the grid's gradient (simcli.collider_mesh_kernels samples the same grid)
        return spec.mesh.normal(x)
    a = np.asarray(spec.a, dtype=np.float64)
    n = np.zeros_like(x)
    if spec.kind == "Plane":
        n[:] = np.asarray(spec.b, dtype=np.float64)
    elif spec.kind == "Sphere":
        d = x - a
        r = np.linalg.norm(d, axis=1)
        n[:, -1] = 1.0
        ok = r > 0
        n[ok] = d[ok] / r[ok, None]
    elif spec.kind == "Box":
        b = np.asarray(spec.b, dtype=np.float64)
        d = x - 0.5 * (a + b)
        sgn = np.where(d < 0, -1.0, 1.0)
        k = np.argmax(np.abs(d) - 0.5 * (b - a), axis=1)  # the first largest q: Taichi's strict >
        n[np.arange(len(x)), k] = sgn[np.arange(len(x)), k]
    elif spec.kind == "Cylinder":
        d = x - a
        ax = spec.axis
        r = d.copy()
        r[:, ax] = 0.0
        rho = np.linalg.norm(r, axis=1)
        rhat = np.zeros_like(x)
        rhat[:, (ax + 1) % x.shape[1]] = 1.0
        ok = rho > 0
        rhat[ok] = r[ok] / rho[ok, None]
        e = np.zeros_like(x)
        e[:, ax] = np.where(d[:, ax] < 0, -1.0, 1.0)
        cap = np.abs(d[:, ax]) - spec.half_height > rho - spec.radius
        n = np.where(cap[:, None], e, rhat)
    else:
        raise ValueError(spec.kind)
    return n


# ------------------------------------------------------------- moving and named colliders

POSE_LEN = 18  # per collider and slot: R (9, row-major dim x dim), moving pivot c (3), v (3), w (3)


@ti.data_oriented
class ColliderPoses:
    """The pose of every collider at two times of the current substep, in one small field uploaded by the
    host once per substep (:meth:`set_time`; no recompilation): slot 0 is the middle of the substep (grid
    nodes), slot 1 its end (particles). Compiled into a solver only when a collider moves or is named
    (``needed``); a still, unnamed collider keeps its world-frame SDF and its code path.

    A moving collider's signed distance at world point x is its body-frame one at ``to_body(x)`` = R^T (x -
    c) + p, its normal ``R n``, the velocity of its surface there ``v + w x (x - c)`` (simcli.motion).
    Named colliders also collect the load the material puts on them (``load``: impulse [N s], then its
    moment about c [N m s], 3 components; z alone in 2D), summed until :meth:`take_loads`.
    """

    def __init__(self, specs: list[ColliderSpec], motions: list, dim: int, dtype: Any) -> None:
        self.specs, self.motions, self.dim, self.dtype = specs, motions, dim, dtype
        self.n = len(specs)
        self.moving = tuple(c.moving for c in specs)
        self.named = tuple(c.name is not None for c in specs)
        self.any_moving = any(self.moving)
        self.any_named = any(self.named)
        self.needed = self.any_moving or self.any_named
        self.t = 0.0

    def allocate(self) -> None:
        if not self.needed:
            return
        nc, f = max(1, self.n), self.dtype
        self.pose = ti.field(f, shape=(2, nc, POSE_LEN))
        self.pivot = ti.Vector.field(self.dim, f, shape=nc)
        self.dt = ti.field(f, shape=())
        self.load = ti.field(ti.f64, shape=(nc, self.dim + 3))
        npf = np.float64 if f == ti.f64 else np.float32
        piv = np.zeros((nc, self.dim), npf)
        for k, c in enumerate(self.specs):
            if c.centre:
                m = self.motions[k]
                piv[k] = m.pivot[: self.dim] if m is not None else c.centre
        self.pivot.from_numpy(piv)
        self.load.fill(0.0)
        self._buf = np.zeros((2, nc, POSE_LEN), npf)  # the host side of ``pose``, refilled every substep
        self._static_filled = False
        self._dt_last = None
        self.set_time(0.0, 0.0)

    def set_time(self, t: float, dt: float) -> None:
        """Upload every collider's pose for the substep [t, t + dt] (host; one small copy)."""
        if not self.needed:
            return
        d = self.dim
        buf = self._buf
        for k, c in enumerate(self.specs):
            m = self.motions[k]
            if m is None and self._static_filled:
                continue  # a still (named) collider's pose never changes: written once
            for slot, ts in enumerate((t + 0.5 * dt, t + dt)):
                if m is None:
                    R, cen, v, w = (
                        np.eye(d).reshape(-1),
                        np.asarray(c.centre or (0.0,) * d),
                        np.zeros(d),
                        np.zeros(3),
                    )
                elif m.constant:  # plain floats, the same arithmetic as pose() (tests/unit/test_motion.py)
                    R9, cen3, v3, w = m.constant_pose_flat(ts)
                    R = [R9[3 * i + j] for i in range(d) for j in range(d)]
                    cen, v = cen3[:d], v3[:d]
                else:
                    ps = m.pose(ts)
                    R, cen, v, w = ps.R.reshape(-1), ps.c, ps.v, ps.w
                row = buf[slot, k]
                row[: d * d] = R
                row[9 : 9 + d] = cen
                row[12 : 12 + d] = v
                row[15:18] = w
        self._static_filled = True
        self._upload(buf)  # (a kernel with an array argument: about half of from_numpy's cost a substep)
        if dt != self._dt_last:  # (dt rarely changes: one field write less a substep)
            self.dt[None] = dt
            self._dt_last = dt
        self.t = t

    @ti.kernel
    def _upload(self, a: ti.types.ndarray()):
        ti.loop_config(serialize=True)  # 36 numbers a collider: no threads to start
        for s, k, i in ti.ndrange(a.shape[0], a.shape[1], a.shape[2]):
            self.pose[s, k, i] = a[s, k, i]

    def max_surface_speed(self, t: float) -> float:
        """Largest speed [m/s] of any point of a moving collider at time t (|v| + |w| times the distance
        from the pivot to the farthest point of the collider; a Plane counts only |v|): for substeps: auto."""
        vmax = 0.0
        for c, m in zip(self.specs, self.motions):
            if m is None:
                continue
            p = m.pose(t)
            reach = 0.0
            if c.kind != "Plane":
                piv = np.asarray(m.pivot[: self.dim])
                a = np.asarray(c.a, float)
                if c.kind == "Box":
                    b = np.asarray(c.b, float)
                    reach = float(np.linalg.norm(np.maximum(np.abs(a - piv), np.abs(b - piv))))
                else:
                    reach = float(np.linalg.norm(a - piv)) + float(np.hypot(c.radius, c.half_height))
            vmax = max(vmax, float(np.linalg.norm(p.v)) + float(np.linalg.norm(p.w)) * reach)
        return vmax

    def take_loads(self) -> np.ndarray:
        """(n, dim + 3) impulse and angular impulse summed since the last call; resets them."""
        if not self.any_named:
            return np.zeros((self.n, self.dim + 3))
        a = self.load.to_numpy()[: self.n]
        self.load.fill(0.0)
        return a

    def loads_by_name(self) -> dict[str, np.ndarray]:
        if not self.any_named:
            return {}
        a = self.take_loads()
        return {c.name: a[k] for k, c in enumerate(self.specs) if c.name is not None}

    @ti.func
    def get(self, slot, k: ti.template()):
        """(R, c, v, w) of collider k in ``slot``."""
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
    def cross(self, w, r):
        """w x r for w (3,) and r (dim,): a dim vector (2D: about z)."""
        out = r * 0.0
        if ti.static(self.dim == 2):
            out = ti.Vector([-w[2] * r[1], w[2] * r[0]])
        else:
            out = w.cross(r)
        return out

    @ti.func
    def moment(self, r, f):
        """r x f as 3 components (2D: only z)."""
        out = ti.Vector.zero(self.dtype, 3)
        if ti.static(self.dim == 2):
            out[2] = r[0] * f[1] - r[1] * f[0]
        else:
            out = r.cross(f)
        return out

    @ti.func
    def to_body(self, k: ti.template(), x, slot):
        R, c, _v, _w = self.get(slot, k)
        return R.transpose() @ (x - c) + self.pivot[k]

    @ti.func
    def normal_to_world(self, k: ti.template(), n, slot):
        R, _c, _v, _w = self.get(slot, k)
        return R @ n

    @ti.func
    def velocity(self, k: ti.template(), x, slot):
        _R, c, v, w = self.get(slot, k)
        return v + self.cross(w, x - c)

    @ti.func
    def add_load(self, k: ti.template(), x, J, slot):
        """The material gave collider k the impulse J [N s] at world point x."""
        _R, c, _v, _w = self.get(slot, k)
        M = self.moment(x - c, J)
        for i in ti.static(range(self.dim)):
            ti.atomic_add(self.load[k, i], ti.cast(J[i], ti.f64))
        for i in ti.static(range(3)):
            ti.atomic_add(self.load[k, self.dim + i], ti.cast(M[i], ti.f64))


def collider_vtk_items(scene: Any, scene_dir: Any = None) -> list[tuple[str, Any, Any]]:
    """(file name, spec, motion) of every named or moving collider of the scene, for
    simcli.io.collider_vtk (which knows no collider model: io sits below this module)."""
    from simcli.motion import collider_motion

    dim = scene.sim.dim
    out = []
    for k, c in enumerate(scene.colliders):
        if c.name is None and c.motion is None:
            continue
        spec = _collider_spec(c, dim, scene, scene_dir)
        out.append((c.name or f"collider{k}", spec, collider_motion(c, dim, scene_dir)))
    specs, motions = _rigid(scene, "specs", scene_dir), _rigid(scene, "motions", scene_dir)
    return out + [(s.name, s, m) for s, m in zip(specs, motions)]
