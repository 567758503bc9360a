"""Plane and Sphere colliders (static or moving) and the domain walls as exact signed distances (Mesh, Box
and Cylinder colliders: mesh_obstacles.py, their triangles in the IPC contact), in numpy (no Taichi: the
scene checks use it too). Each obstacle is convex, so its signed distance is a convex function of position:
``first_contact`` relies on it. ``Obstacles(..., mesh_boxes=False)`` keeps Box and Cylinder colliders here
too (the scene checks' vertex-inside / too-close test against their exact shapes)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# the facet stand-off's allowance for a triangle's growth over its rest size (stretch): its enclosing
# radius is taken this much larger (see Obstacles.set_facets)
FACET_STRETCH = 1.1


def enclosing_radius(x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Radius of each triangle's smallest enclosing circle: its circumradius when acute, half its longest
    edge otherwise (then the circle on that edge holds the third vertex): a point m with |v - m| <= r for
    the three vertices v."""
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
    la = np.einsum("ij,ij->i", b - c, b - c)  # squared edge lengths opposite each vertex
    lb = np.einsum("ij,ij->i", c - a, c - a)
    lc = np.einsum("ij,ij->i", a - b, a - b)
    longest = np.maximum(np.maximum(la, lb), lc)
    obtuse = 2.0 * longest >= la + lb + lc  # the longest edge's square at least the other two's sum
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)  # twice the area
    circ = np.sqrt(la * lb * lc) / np.maximum(2.0 * area2, 1e-300)  # abc / (4 area)
    return np.where(obtuse, 0.5 * np.sqrt(longest), circ)


@dataclass(frozen=True)
class Spec:
    kind: str  # Plane | Box | Sphere | Cylinder
    a: tuple  # Plane: point, Box: lower, Sphere/Cylinder: center
    b: tuple  # Plane: unit normal, Box: upper, others: zeros
    radius: float = 0.0
    half_height: float = 0.0
    axis: int = 2
    friction: float = 0.0


def _spec(c) -> Spec:
    if c.type == "Plane":
        n = np.asarray(c.normal, float)
        return Spec("Plane", tuple(c.point), tuple(n / np.linalg.norm(n)), friction=c.friction)
    if c.type == "Box":
        return Spec("Box", tuple(c.lower), tuple(c.upper), friction=c.friction)
    if c.type == "Sphere":
        return Spec("Sphere", tuple(c.center), (0.0,) * 3, radius=c.radius, friction=c.friction)
    if c.type == "Cylinder":
        return Spec(
            "Cylinder",
            tuple(c.center),
            (0.0,) * 3,
            radius=c.radius,
            half_height=0.5 * c.height,
            axis="xyz".index(c.axis),
            friction=c.friction,
        )
    raise ValueError(f"FEM.Cloth: collider type {c.type} is not supported")


class Obstacles:
    """Colliders (Plane, Box, Sphere, Cylinder; static or moving on a prescribed rigid motion) and the domain
    walls as exact signed distances. A moving collider's distance at time t is its static shape's in its
    body frame, pose(t).to_body(x); within a step the cloth's motion relative to it is taken as linear in
    that frame (exact for translations), which is what ``first_contact`` checks."""

    def __init__(self, scene, scene_dir=None, mesh_boxes: bool = True):
        from simcli.motion import collider_motion
        from simcli.solvers.fem.cloth.mesh_obstacles import MESH_TYPES

        as_mesh = MESH_TYPES if mesh_boxes else ("Mesh",)  # (Box, Cylinder: exact signed distances)
        convex = [(i, c) for i, c in enumerate(scene.colliders) if c.type not in as_mesh]
        self.index = [i for i, _ in convex]  # scene.colliders index of each spec
        self.specs = [_spec(c) for _, c in convex]
        self.motions = [collider_motion(c, 3, scene_dir) for _, c in convex]
        # Mesh, Box and Cylinder colliders are not signed distances here: their triangles join the
        # cloth's ipctk collision mesh (mesh_obstacles.py); their motions count for `moving` and next_key
        self.mesh_motions = [collider_motion(c, 3, scene_dir) for c in scene.colliders if c.type in as_mesh]
        self.moving = any(m is not None for m in self.motions + self.mesh_motions)
        lo, hi = scene.domain.bounds(3)
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.wall_mu = []
        for axis in range(3):
            for side in ("-", "+"):
                self.wall_mu.append(float(scene.domain.face("xyz"[axis] + side).friction))
        self.offsets: list[np.ndarray | None] = [None] * len(self.specs)  # set_facets

    def set_facets(self, x: np.ndarray, tris: np.ndarray) -> None:
        """Keep the cloth's triangles, not only its vertices, out of every Sphere: a flat triangle whose
        vertices lie outside a sphere of radius R' = sqrt(R^2 + r^2), r its smallest enclosing circle's
        radius (centre m), lies outside the sphere of radius R (centre c): |y - c|^2 - |y - m|^2 is affine
        in y and at each vertex >= R'^2 - r^2 = R^2, so it is >= R^2 over the triangle, and then
        |y - c|^2 >= R^2 + |y - m|^2 >= R^2 at every point y of it. So each vertex keeps
        sqrt(R^2 + r_i^2) - R off the sphere (r_i: the largest r of the triangles around it, at their rest
        shape times FACET_STRETCH): about r_i^2 / (2 R), 0.25 mm for 1 cm triangles on a 0.2 m ball,
        6 mm for 5 cm ones on a 0.1 m ball (a flat facet cannot wrap a sphere closer). The offset distance
        |x - c| - R - off_i stays convex in x_i (first_contact relies on it). Planes, Boxes and Cylinders
        are exact already (their flat faces and edges: mesh_obstacles.py).

        Still or moving alike. (A moving one first jammed the fast-sphere hard case's Dirichlet steps: the
        inexact Newton direction let the vertices in the sphere's barrier lag it; ClothSolver.STALL_ALPHA.)"""
        if not any(c.kind == "Sphere" for c in self.specs):
            return
        r = FACET_STRETCH * enclosing_radius(x, tris)
        ri = np.zeros(len(x))
        for j in range(3):
            np.maximum.at(ri, tris[:, j], r)
        for k, c in enumerate(self.specs):
            if c.kind == "Sphere":
                self.offsets[k] = np.sqrt(c.radius**2 + ri**2) - c.radius

    def _offset(self, k: int, d: np.ndarray) -> np.ndarray:
        """Obstacle k's signed distances d less its per-vertex facet stand-off (when d is one per vertex)."""
        off = self.offsets[k]
        return d if off is None or len(off) != len(d) else d - off

    def _pose(self, k: int, t: float | None):
        """The pose of obstacle k (>= 6: a collider) at time t, or None (static, or a wall)."""
        if k < 6 or t is None:
            return None
        m = self.motions[k - 6]
        return None if m is None else m.pose(t)

    def first_contact(self, x: np.ndarray, p: np.ndarray, iters: int = 8, t0=None, t1=None) -> float:
        """A step alpha (<= 1) below the first time any vertex x_i + alpha p_i touches an obstacle, times 0.9,
        with moving obstacles going from their pose at t0 to that at t1 meanwhile (the relative motion linear
        in each obstacle's body frame). Every obstacle's signed distance is convex (convex shapes), so along
        a ray f(alpha) lies above its tangents: Newton iterations from alpha = 0 increase monotonically
        towards the first root without passing it (and a ray with f' >= 0 never reaches it)."""
        amin = 1.0
        for k in range(6 + len(self.specs)):
            P0, P1 = self._pose(k, t0), self._pose(k, t1)
            if P0 is None:
                y, q = x, p
            else:  # body-frame points at the start and the end of the step
                y = P0.to_body(x)
                q = P1.to_body(x + p) - y
            a = np.zeros(len(x))
            f, nk = self._one(k, y)
            slope0 = np.einsum("ij,ij->i", nk, q)
            slope = slope0
            live = slope < 0
            for _ in range(iters):
                if not live.any():
                    break
                a = np.where(live, a + f / np.where(live, -slope, 1.0), a)
                beyond = a >= 1.0 / 0.9
                live &= ~beyond
                dk, nk = self._one(k, y + a[:, None] * q)
                f, slope = dk, np.einsum("ij,ij->i", nk, q)
                live &= slope < 0
                # f ~ 0: converged on a touching ray; keep a (left of the root)
                live &= f > 1e-12
            hit = (a < 1.0 / 0.9) & (slope0 < 0)
            # rays still decreasing after the iterations: a is a lower bound of their root (safe)
            if hit.any():
                amin = min(amin, 0.9 * float(a[hit].min()))
        return amin

    def next_key(self, t0: float, t1: float) -> float:
        """t1, or the first keyframe time of a moving collider inside (t0, t1) (a kink of its path)."""
        out = t1
        for m in self.motions + self.mesh_motions:
            if m is not None and m.times is not None:
                k = m.times[(m.times > t0 * (1 + 1e-12) + 1e-15) & (m.times < t1)]
                if len(k):
                    out = min(out, float(k.min()))
        return out

    def _one(self, k: int, x: np.ndarray):
        """Signed distance and outward normal of obstacle k in its body frame."""
        if k < 6:
            axis, side = divmod(k, 2)
            n = np.zeros((len(x), 3))
            n[:, axis] = 1.0 if side == 0 else -1.0
            d = (x[:, axis] - self.lo[axis]) if side == 0 else (self.hi[axis] - x[:, axis])
            return d, n
        d, n = _sdf(self.specs[k - 6], x)
        return self._offset(k - 6, d), n

    def surface_displacement(self, x: np.ndarray, t0: float, t1: float) -> np.ndarray:
        """(k, n, 3): how far the material point of each obstacle at x moves from t0 to t1 (0 for static
        ones and walls)."""
        u = np.zeros((6 + len(self.specs), len(x), 3))
        for k in range(6, 6 + len(self.specs)):
            P0, P1 = self._pose(k, t0), self._pose(k, t1)
            if P0 is not None:
                u[k] = P1.to_world(P0.to_body(x)) - x
        return u

    def distances(self, x: np.ndarray, t: float | None = None):
        """(k, n) signed distances, (k, n, 3) outward unit normals and (k,) friction of every obstacle (moving
        ones at their pose at time t; t None: at t = 0)."""
        ds, ns, mus = [], [], []
        for axis in range(3):
            for side in (-1, 1):
                n = np.zeros((len(x), 3))
                n[:, axis] = -side
                d = (x[:, axis] - self.lo[axis]) if side < 0 else (self.hi[axis] - x[:, axis])
                ds.append(d)
                ns.append(n)
        mus += self.wall_mu
        for k, c in enumerate(self.specs):
            P = self._pose(k + 6, t)
            if P is None:
                d, n = _sdf(c, x)
            else:
                d, n = _sdf(c, P.to_body(x))
                n = n @ P.R.T
            ds.append(self._offset(k, d))
            ns.append(n)
            mus.append(float(c.friction))
        return np.array(ds), np.array(ns), np.array(mus)


def _sdf(c, x):
    a, b = np.asarray(c.a, float), np.asarray(c.b, float)
    if c.kind == "Plane":
        return (x - a) @ b, np.broadcast_to(b, x.shape).copy()
    if c.kind == "Sphere":
        r = x - a
        ln = np.linalg.norm(r, axis=1)
        return ln - c.radius, r / np.maximum(ln, 1e-300)[:, None]
    if c.kind == "Box":
        ctr, half = 0.5 * (a + b), 0.5 * (b - a)
        q = np.abs(x - ctr) - half
        sgn = np.sign(x - ctr)
        sgn[sgn == 0] = 1.0
        outside = np.maximum(q, 0.0)
        lo = np.linalg.norm(outside, axis=1)
        inside = np.minimum(q.max(axis=1), 0.0)
        d = lo + inside
        n = outside * sgn / np.maximum(lo, 1e-300)[:, None]
        k = np.argmax(q, axis=1)
        nin = np.zeros_like(x)
        nin[np.arange(len(x)), k] = sgn[np.arange(len(x)), k]
        n = np.where((lo > 0)[:, None], n, nin)
        return d, n
    if c.kind == "Cylinder":
        ax = c.axis
        r = x - a
        rad = r.copy()
        rad[:, ax] = 0
        lr = np.linalg.norm(rad, axis=1)
        dr = lr - c.radius
        dz = np.abs(r[:, ax]) - c.half_height
        nr = rad / np.maximum(lr, 1e-300)[:, None]
        nz = np.zeros_like(x)
        nz[:, ax] = np.sign(r[:, ax])
        out = np.stack([np.maximum(dr, 0), np.maximum(dz, 0)], 1)
        lo = np.linalg.norm(out, axis=1)
        d = lo + np.minimum(np.maximum(dr, dz), 0.0)
        n = (nr * out[:, :1] + nz * out[:, 1:]) / np.maximum(lo, 1e-300)[:, None]
        n = np.where((lo > 0)[:, None], n, np.where((dr > dz)[:, None], nr, nz))
        return d, n
    raise ValueError(f"FEM.Cloth: unknown collider {c.kind}")
