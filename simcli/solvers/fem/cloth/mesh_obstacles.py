"""`type: Mesh` and `type: Box` colliders for FEM.Cloth, the IPC way (Li et al. 2020): the collider's own
triangles join the cloth's in one ipctk collision mesh as obstacle vertices (indices n .. n + m - 1 after the
n cloth vertices) whose positions are prescribed, so the barrier, the lagged friction and the continuous
collision check treat cloth-collider point-triangle and edge-edge pairs exactly as the cloth's own (no
signed-distance grid).

* Static colliders: their vertices stay where the scene puts them (the file, scaled, rotated, translated).
* Moving colliders (simcli.motion: constant linear/angular velocity about a pivot, keyframes, CSV): within a
  Newton step the obstacle vertices go on straight lines from their current positions to their pose at the
  step's end time (the trajectory ipctk's CCD checks); a step cut short by the CCD leaves them on that
  chord, which is where the solver keeps them (``ClothSolver.vobs``), so every accepted state is the one
  the CCD found intersection-free. A finished substep puts them exactly at pose(t).
* ipctk's static-obstacle filter keeps collider-collider pairs out of the broad phase.
* Loads: the contact potential's gradient on the obstacle vertices is the force the cloth puts on them
  (the barrier's and friction's reaction, exactly minus what the cloth receives); its impulse over each
  substep and moment about the collider's moving pivot go to ``collider_loads``.
* A `type: Box` collider enters as its 12 exact triangles (8 corners, outward faces; pivot its centre, as
  simcli.motion takes it): a convex signed distance per cloth vertex kept the vertices out of the box but
  not the box's edges out of the cloth's triangles (a sheet draped over a box edge was cut by it).
* A `type: Cylinder` collider enters as a circumscribed prism (:func:`cylinder_mesh` with
  ``circumscribed=True``: every facet outside the exact surface or on it, within contact_distance / 2 of
  it): a signed distance per cloth vertex kept the vertices out but not the edges and triangles (its rims
  cut a sheet draped over them). Outside the triangles is outside the exact cylinder, so IPC's guarantee
  covers it too; the sheet rests up to contact_distance / 2 farther out than on the exact surface. Pivot:
  its centre (simcli.motion). :func:`sphere_mesh` (a circumscribed icosphere) is not used for Sphere
  colliders yet (docs/FEM.md, "Remaining gaps").
* Free rigid bodies (simcli.rigid, ``rigid_bodies``) enter the same way, after the colliders: a Box body its
  12 triangles, a Mesh body its file's triangles, a Sphere an inscribed icosphere and a Cylinder an inscribed
  prism (:func:`body_mesh`, fine enough that the facets lie within contact_distance / 2 of the true
  surface up to a radius of 10^4 contact_distance). Their pose over a substep is an unknown of the cloth's
  Newton system (rigid_dofs.py; held dofs move at their prescribed rate), and the reaction the cloth gives
  them goes back to the rigid world (ClothSolver.collider_poses) instead of the named colliders' force
  output.
"""

from __future__ import annotations

import numpy as np

from simcli.motion import collider_centre, collider_motion

# collider types whose triangles join the cloth's collision mesh (Box and Mesh exact; Cylinder circumscribed
# within contact_distance / 2); Plane and Sphere colliders and the walls stay exact signed distances (a
# circumscribed Sphere, sphere_mesh, jammed the fast-sphere hard case: docs/FEM.md, "Remaining gaps")
MESH_TYPES = ("Mesh", "Box", "Cylinder")
ROUND_TYPES = ("Cylinder",)  # triangulated: the scene checks keep their exact signed distance too

# the 12 outward triangles of a box from its corners numbered by bits (x: 1, y: 2, z: 4 set = upper side)
_BOX_TRIS = np.array(
    [
        [0, 2, 3], [0, 3, 1],  # z-
        [4, 5, 7], [4, 7, 6],  # z+
        [0, 1, 5], [0, 5, 4],  # y-
        [2, 6, 7], [2, 7, 3],  # y+
        [0, 4, 6], [0, 6, 2],  # x-
        [1, 3, 7], [1, 7, 5],  # x+
    ],
    np.int64,
)  # fmt: skip


def box_mesh(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """(8, 3) corners and (12, 3) outward triangles of the axis-aligned box [lower, upper]."""
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    V = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
    return V, _BOX_TRIS.copy()


def icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: the icosahedron with each triangle split in four ``level`` times, vertices on the
    unit sphere, outward triangles."""
    g = (1.0 + 5.0**0.5) / 2.0
    V = [[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0], [0, -1, g], [0, 1, g], [0, -1, -g], [0, 1, -g]]
    V += [[g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]]
    T = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2]]
    T += [[10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5]]
    T += [[2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    V = [np.asarray(v, float) / np.linalg.norm(v) for v in V]
    for _ in range(level):
        mid: dict[tuple[int, int], int] = {}

        def m(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                p = V[a] + V[b]
                V.append(p / np.linalg.norm(p))
                mid[key] = len(V) - 1
            return mid[key]

        T = [t for a, b, c in T for t in ([a, m(a, b), m(c, a)], [b, m(b, c), m(a, b)], [c, m(c, a), m(b, c)],
                                         [m(a, b), m(b, c), m(c, a)])]  # fmt: skip
    return np.array(V), np.array(T, np.int64)


def _sag_level(radius: float, dhat: float) -> int:
    """The icosphere level whose facets lie within dhat / 2 of the sphere (the centre of a face of edge
    angle a sits R a^2 / 6 inside it; the icosahedron's edge angle is 1.107 rad, halved each level), 1..6
    (level 6, 81920 triangles, holds that up to R = 10^4 dhat)."""
    a, lev = 1.1071487, 0
    while lev < 6 and (lev < 1 or radius * a * a / 6.0 > 0.5 * dhat):
        a, lev = 0.5 * a, lev + 1
    return lev


_FACE_DIST: dict[int, float] = {}


def icosphere_face_distance(level: int) -> float:
    """The smallest distance from the centre to a face plane of the unit icosphere of ``level`` (its
    inscribed ball's radius, < 1)."""
    if level not in _FACE_DIST:
        V, T = icosphere(level)
        a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
        nrm = np.cross(b - a, c - a)
        _FACE_DIST[level] = float(np.min(np.einsum("ij,ij->i", nrm, a) / np.linalg.norm(nrm, axis=1)))
    return _FACE_DIST[level]


def _circumscribed_level(radius: float, dhat: float) -> int:
    """The coarsest icosphere level (1..6) whose circumscribed copy (scaled by 1 / its inscribed radius) lies
    within dhat / 2 of the sphere: its vertices, the farthest points, at R / d_min (level 6 holds that up to
    R of about 1.3 10^4 dhat; beyond it the facets lie farther out: a larger gap, never an intersection)."""
    lev = 1
    while lev < 6 and radius * (1.0 / icosphere_face_distance(lev) - 1.0) > 0.5 * dhat:
        lev += 1
    return lev


def sphere_mesh(center, radius: float, dhat: float) -> tuple[np.ndarray, np.ndarray]:
    """A circumscribed icosphere of the sphere (every facet at distance >= radius from the centre, its
    vertices within dhat / 2 of the sphere while level 6 suffices); outward triangles."""
    lev = _circumscribed_level(float(radius), dhat)
    V, T = icosphere(lev)
    return V * (float(radius) / icosphere_face_distance(lev)) + np.asarray(center, float), T


def cylinder_mesh(
    center, radius, height, axis: int, dhat: float, circumscribed: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """A prism of the cylinder (segments so the flats lie within dhat / 2 of the round side; 12 to 256), its
    caps fans about their centres; outward triangles. Inscribed (ring on the circle: a rigid body's) or
    ``circumscribed`` (ring at radius / cos(pi / n): the flats touch the round side, so the exact cylinder,
    rims included, lies inside the prism: a collider's)."""
    n = 12  # the largest gap between flat and round side: R (1 - cos(pi / n)) inscribed, R (1 / cos - 1) out

    def sag(k):
        return radius * (1.0 / np.cos(np.pi / k) - 1.0 if circumscribed else 1.0 - np.cos(np.pi / k))

    while n < 256 and sag(n) > 0.5 * dhat:
        n *= 2
    ang = 2 * np.pi * np.arange(n) / n
    u, w = [a for a in range(3) if a != axis]
    ring = np.zeros((n, 3))
    rr = radius / np.cos(np.pi / n) if circumscribed else radius
    ring[:, u], ring[:, w] = rr * np.cos(ang), rr * np.sin(ang)
    c = np.asarray(center, float)
    lo, hi = ring.copy(), ring.copy()
    lo[:, axis], hi[:, axis] = -0.5 * height, 0.5 * height
    caps = np.zeros((2, 3))
    caps[0, axis], caps[1, axis] = -0.5 * height, 0.5 * height
    V = np.concatenate([lo, hi, caps]) + c
    i = np.arange(n)
    j = (i + 1) % n
    T = np.concatenate(
        [
            np.stack([i, j, n + j], 1),
            np.stack([i, n + j, n + i], 1),
            np.stack([np.full(n, 2 * n), j, i], 1),  # the lower cap
            np.stack([np.full(n, 2 * n + 1), n + i, n + j], 1),  # the upper cap
        ]
    )
    if (u, w, axis) not in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # a left-handed (u, w, axis): flip
        T = T[:, [0, 2, 1]]
    return V, T.astype(np.int64)


def body_mesh(rb, scene, scene_dir, dhat: float) -> tuple[np.ndarray, np.ndarray]:
    """The triangles of rigid body ``rb`` (its body frame: its placement at t = 0) that FEM.Cloth meets."""
    m = rb.morph
    if m.type == "Box":
        lo, hi = m.bounds()
        return box_mesh(lo, hi)
    if m.type == "Sphere":
        V, T = icosphere(_sag_level(float(m.radius), dhat))
        return V * float(m.radius) + np.asarray(m.center, float), T
    if m.type == "Cylinder":
        return cylinder_mesh(m.center, float(m.radius), float(m.height), "xyz".index(m.axis), dhat)
    if m.type == "Mesh":
        from simcli.rigid.body import mesh_sdf

        sdf = mesh_sdf(rb, scene, scene_dir)
        return np.asarray(sdf.vertices, float), np.asarray(sdf.triangles, np.int64)
    raise ValueError(f"FEM.Cloth meets Box, Sphere, Cylinder and Mesh rigid bodies, not {m.type}")


class MeshObstacles:
    """Every `type: Mesh`, `Box` and `Cylinder` collider of a scene, then (given the rigid world)
    every rigid body: obstacle vertices and triangles (numbered 0 .. m-1)."""

    def __init__(self, scene, scene_dir=None, world=None, dhat: float | None = None):
        from simcli.geometry.mesh import load_mesh_morph

        if dhat is None:  # the scene's: Cylinder triangulations (and bodies') depend on it
            dhat = float(scene.solvers.fem.contact_distance)
        self.index, self.names, self.friction, self.motions, self.centres = [], [], [], [], []
        vs, ts, off = [], [], [0]
        for i, c in enumerate(scene.colliders):
            if c.type not in MESH_TYPES:
                continue
            if c.type == "Box":
                bv, bt = box_mesh(c.lower, c.upper)
            elif c.type == "Cylinder":
                bv, bt = cylinder_mesh(
                    c.center, float(c.radius), float(c.height), "xyz".index(c.axis), dhat, circumscribed=True
                )
            else:
                mesh = load_mesh_morph(c, scene_dir)
                bv, bt = mesh.vertices, mesh.triangles
            self.index.append(i)
            self.names.append(getattr(c, "name", None))
            self.friction.append(float(c.friction))
            self.motions.append(collider_motion(c, 3, scene_dir))
            self.centres.append(collider_centre(c, 3))
            vs.append(np.asarray(bv, float))
            ts.append(np.asarray(bt, np.int64) + off[-1])
            off.append(off[-1] + len(bv))
        # rigid bodies: entries len(index) .. ; body k is row world.n_colliders + k of the loads it reads
        self.body_rows: dict[str, int] = {}
        for k, b in enumerate(world.bodies if world is not None else []):
            bv, bt = body_mesh(b.cfg, scene, scene_dir, dhat)
            self.names.append(b.name)
            self.friction.append(float(b.cfg.friction))
            self.motions.append(b.motion)
            self.centres.append(np.asarray(b.pivot, float))
            self.body_rows[b.name] = world.n_colliders + k
            vs.append(np.asarray(bv, float))
            ts.append(np.asarray(bt, np.int64) + off[-1])
            off.append(off[-1] + len(bv))
        self.n_entries = len(self.names)
        self.offsets = off
        self.V0 = np.concatenate(vs) if vs else np.zeros((0, 3))
        self.T = np.concatenate(ts) if ts else np.zeros((0, 3), np.int64)
        self.m = len(self.V0)
        self.moving = any(mo is not None for mo in self.motions)
        self.vertex_mu = (
            np.concatenate([np.full(off[k + 1] - off[k], self.friction[k]) for k in range(self.n_entries)])
            if vs
            else np.zeros(0)
        )

    def append_surface(self, V: np.ndarray, T: np.ndarray, friction: float) -> tuple[int, int]:
        """Add a surface whose vertices the caller moves (an FEM solid's boundary): unnamed, no motion here.
        Returns its obstacle-vertex range."""
        lo = self.m
        self.V0 = np.concatenate([self.V0, np.asarray(V, float)])
        self.T = np.concatenate([self.T, np.asarray(T, np.int64) + lo])
        self.names.append(None)
        self.friction.append(float(friction))
        self.motions.append(None)
        self.centres.append(np.zeros(3))
        self.offsets.append(lo + len(V))
        self.n_entries += 1
        self.m = len(self.V0)
        self.vertex_mu = np.concatenate([self.vertex_mu, np.full(len(V), float(friction))])
        return lo, self.m

    def __len__(self) -> int:
        return len(self.index)

    def positions(self, t: float | None) -> np.ndarray:
        """(m, 3) world positions of every obstacle vertex at time t (their pose at t = 0 for None)."""
        out = self.V0.copy()
        for k, mo in enumerate(self.motions):
            if mo is None or t is None:
                continue
            lo, hi = self.offsets[k], self.offsets[k + 1]
            out[lo:hi] = mo.pose(float(t)).to_world(self.V0[lo:hi])
        return out

    def pivots(self, t: float | None) -> list[np.ndarray]:
        """The point each collider's moment is taken about: its moving pivot at time t (its default
        pivot, the file's origin after the transform, when it does not move)."""
        out = []
        for k, mo in enumerate(self.motions):
            out.append(self.centres[k] if mo is None or t is None else np.asarray(mo.pose(float(t)).c, float))
        return out

    def loads(
        self, force: np.ndarray, x_obs: np.ndarray, t: float | None, dt: float
    ) -> dict[str, np.ndarray]:
        """Named collider -> (6,) impulse [N s] and its moment [N m s] over dt from per-vertex forces (m, 3)
        on the obstacle vertices at positions x_obs."""
        out = {}
        piv = self.pivots(t)
        for k, name in enumerate(self.names):
            if name is None:
                continue
            lo, hi = self.offsets[k], self.offsets[k + 1]
            f = force[lo:hi]
            J = dt * f.sum(axis=0)
            M = dt * np.cross(x_obs[lo:hi] - piv[k], f).sum(axis=0)
            out[name] = np.concatenate([J, M])
        return out


def blend_mu(a: float, b: float) -> float:
    """ipctk's friction blend for the combined mesh: obstacle vertices carry -(1 + mu) (a marker), cloth
    vertices the cloth's mu; a cloth-obstacle pair takes the collider's mu, a cloth-cloth pair the cloth's."""
    if a < 0:
        return -a - 1.0
    if b < 0:
        return -b - 1.0
    return 0.5 * (a + b)


def initial_problems(x: np.ndarray, t: np.ndarray, scene, scene_dir, dhat: float) -> list[str]:
    """Messages for a cloth (vertices x, triangles t) that starts intersecting, inside or within dhat of a
    Mesh or Box collider (a Cylinder's triangles: intersecting or inside) at its pose at t = 0,
    or of a rigid body (located: the collider's or body's index and the first point)."""
    out = []
    if any(c.type in MESH_TYPES for c in scene.colliders):
        mo = MeshObstacles(scene, scene_dir)
        V = mo.positions(0.0)
        for k, ci in enumerate(mo.index):
            lo, hi = mo.offsets[k], mo.offsets[k + 1]
            Tk = mo.T[(mo.T >= lo).all(axis=1) & (mo.T < hi).all(axis=1)] - lo
            typ = scene.colliders[ci].type
            # a Cylinder's facets lie up to dhat / 2 outside its exact surface, whose own signed
            # distance the scene checks hold to dhat (checks.py): only crossing and inside are asked here
            msg = _initial_problem(
                x, t, V[lo:hi], Tk, f"colliders.{ci} ({typ})", dhat, near=typ not in ROUND_TYPES
            )
            if msg:
                out.append(msg)
    for i, rb in enumerate(getattr(scene, "rigid_bodies", None) or []):
        try:  # a Mesh body's own problems (file, closed surface) are reported by the rigid body checks
            Vb, Tb = body_mesh(rb, scene, scene_dir, dhat)
        except (ValueError, OSError):
            continue
        msg = _initial_problem(x, t, Vb, Tb, f"rigid_bodies.{i} ('{rb.name}', {rb.morph.type})", dhat)
        if msg:
            out.append(msg)
    return out


def _initial_problem(x, t, Vk, Tk, what: str, dhat: float, near: bool = True) -> str | None:
    """The cloth (x, t) against one obstacle's triangles (Vk, Tk): crossing, a vertex inside, or (with
    ``near``) closer than dhat; None when clear."""
    from simcli.collider_mesh import mesh_distance
    from simcli.geometry.mesh import TriMesh, points_inside_mesh
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections

    n = len(x)
    X = np.concatenate([x, Vk])
    T = np.concatenate([t, Tk + n])
    hits = [
        h for h in edge_triangle_intersections(X, T) if (h[0][0] < n) == (h[1] >= len(t))
    ]  # a cloth edge through an obstacle triangle or an obstacle edge through a cloth triangle
    if hits:
        return (
            f"the cloth intersects {what} at the start (near {np.round(hits[0][2], 6).tolist()}); move the "
            "cloth or the obstacle apart"
        )
    vol = float(abs(np.einsum("ij,ij->i", Vk[Tk[:, 0]], np.cross(Vk[Tk[:, 1]], Vk[Tk[:, 2]])).sum()) / 6)
    ins = points_inside_mesh(TriMesh(Vk, Tk, vol, "collider"), x)
    if ins.any():
        return (
            f"{int(ins.sum())} cloth vertex(es) start inside {what} (first at "
            f"{np.round(x[np.argmax(ins)], 6).tolist()}); the cloth must start outside it: move it"
        )
    if not near:
        return None
    # cloth vertices to the obstacle's triangles and its vertices to the cloth's, each only where the
    # other's bounding box (grown by dhat) reaches (brute force within)
    near_x = np.all((x >= Vk.min(axis=0) - dhat) & (x <= Vk.max(axis=0) + dhat), axis=1)
    near_v = np.all((Vk >= x.min(axis=0) - dhat) & (Vk <= x.max(axis=0) + dhat), axis=1)
    xs, vs = x[near_x], Vk[near_v]
    d1 = mesh_distance(Vk, Tk, xs) if len(xs) else np.full(1, np.inf)
    d2 = mesh_distance(x, t, vs) if len(vs) else np.full(1, np.inf)
    if min(d1.min(), d2.min()) < dhat:
        p = xs[np.argmin(d1)] if d1.min() <= d2.min() else vs[np.argmin(d2)]
        return (
            f"the cloth starts closer than solvers.fem.contact_distance ({dhat:g} m) to {what} "
            f"(distance {min(d1.min(), d2.min()):.3g} m near {np.round(p, 6).tolist()}): move the cloth away"
        )
    return None
