"""Rigid-wall and rigid-rigid contact on the host (numpy): sequential velocity impulses.

Each body's surface is represented by sample points in its body frame (a Box: its corners, edge and face
points; a Sphere: exact against planes and spheres, points otherwise; a Cylinder: points on its rims and
caps; a Mesh: its vertices, edge midpoints and face centroids, and against the walls the vertices of its
convex hull; its signed distance is its grid's, as the materials see it). A contact is a sample point of one
body inside (or, within the substep, reaching) the domain's walls or another body's signed distance; a pair
of spheres is exact. Each contact gets a normal impulse that removes the approaching normal velocity
(restitution e: reverses e of it; a penetration is pushed out at ERP of its depth per substep), and a
Coulomb friction impulse of at most mu times it, applied to both bodies (equal and opposite: momentum is
conserved between bodies); a few Gauss-Seidel sweeps over the contacts.
"""

from __future__ import annotations

import math

import numpy as np

ITERATIONS = 6
ERP = 0.2  # share of a penetration depth removed per substep (Baumgarte)
MESH_DENSE = 2000  # a Mesh body with more vertices is sampled by its vertices only (no edge or face points)


def surface_points(spec, dim: int, n: int = 4) -> np.ndarray:
    """Sample points (k, dim) on a body's surface in its body frame."""
    if spec.kind == "Mesh":
        V = np.asarray(spec.mesh.vertices, float)
        if n <= 1 or len(V) > MESH_DENSE:  # a dense mesh's vertices already sample its faces finely
            return V
        T = np.asarray(spec.mesh.triangles, np.int64)
        if T.shape[1] == 2:  # 2D: a polygon's vertices and its edges' quarter points
            t = np.array([0.25, 0.5, 0.75])[:, None, None]
            E = (V[T[:, 0]] + t * (V[T[:, 1]] - V[T[:, 0]])).reshape(-1, V.shape[1])
            return np.concatenate([V, E])
        e = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
        e = np.unique(e, axis=0)
        return np.concatenate([V, 0.5 * (V[e[:, 0]] + V[e[:, 1]]), V[T].mean(axis=1)])
    a = np.asarray(spec.a, float)
    if spec.kind == "Box":
        b = np.asarray(spec.b, float)
        t = np.linspace(0.0, 1.0, n + 1)
        grids = np.meshgrid(*([t] * dim), indexing="ij")
        u = np.stack([g.ravel() for g in grids], axis=1)
        on = np.any((u == 0.0) | (u == 1.0), axis=1)
        return a + u[on] * (b - a)
    if spec.kind == "Sphere":
        if dim == 2:
            th = np.linspace(0, 2 * math.pi, 8 * n, endpoint=False)
            return a + spec.radius * np.stack([np.cos(th), np.sin(th)], axis=1)
        k = 16 * n * n
        i = np.arange(k) + 0.5
        phi = np.arccos(1 - 2 * i / k)
        th = math.pi * (1 + 5**0.5) * i
        return a + spec.radius * np.stack(
            [np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1
        )
    # Cylinder (3D)
    ax = spec.axis
    e1, e2 = (ax + 1) % 3, (ax + 2) % 3
    th = np.linspace(0, 2 * math.pi, 8 * n, endpoint=False)
    pts = []
    for s in (-1.0, 1.0):
        for rr in (1.0, 0.5, 0.0):
            p = np.zeros((len(th), 3))
            p[:, e1] = spec.radius * rr * np.cos(th)
            p[:, e2] = spec.radius * rr * np.sin(th)
            p[:, ax] = s * spec.half_height
            pts.append(p)
    for s in np.linspace(-1, 1, n + 1)[1:-1]:
        p = np.zeros((len(th), 3))
        p[:, e1] = spec.radius * np.cos(th)
        p[:, e2] = spec.radius * np.sin(th)
        p[:, ax] = s * spec.half_height
        pts.append(p)
    return a + np.concatenate(pts)


def wall_points(spec, dim: int) -> np.ndarray:
    """The points of a convex body that can touch a plane first (body frame): a Box's corners, a
    Cylinder's rims (a Sphere is exact and needs none)."""
    if spec.kind == "Box":
        return surface_points(spec, dim, n=1)
    if spec.kind == "Cylinder":
        P = surface_points(spec, dim, n=4)
        k = 8 * 4  # points per ring; rings 0 and 3 are the two rims (see surface_points)
        return np.concatenate([P[:k], P[3 * k : 4 * k]])
    if spec.kind == "Mesh":  # a plane meets a solid first at a vertex of its convex hull
        from scipy.spatial import ConvexHull

        V = np.asarray(spec.mesh.vertices, float)
        try:
            return V[ConvexHull(V).vertices]
        except Exception:  # flat or degenerate hull (validate refuses those meshes): every vertex
            return V
    return surface_points(spec, dim)


def bounding_radius(spec, dim: int) -> float:
    c = np.asarray(spec.centre, float) if spec.centre else np.asarray(spec.a, float)
    return float(np.max(np.linalg.norm(surface_points(spec, dim, n=1) - c, axis=1)))


def sdf_local(spec, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(phi (k,), outward normal (k, dim)) of a body-frame shape at body-frame points x (k, dim)."""
    if spec.kind == "Plane":  # a scene collider (simcli.rigid.world: bodies against colliders)
        nrm = np.asarray(spec.b, float)
        x = np.asarray(x, float)
        return (x - np.asarray(spec.a, float)) @ nrm, np.broadcast_to(nrm, x.shape).copy()
    if spec.kind == "Mesh":  # the grid's trilinear phi and its central-difference gradient
        x = np.asarray(x, float).reshape(-1, np.asarray(spec.mesh.vertices).shape[1])
        return spec.mesh.sample(x), spec.mesh.normal(x)
    a = np.asarray(spec.a, float)
    if spec.kind == "Sphere":
        d = x - a
        r = np.linalg.norm(d, axis=1)
        n = d / np.maximum(r, 1e-300)[:, None]
        return r - spec.radius, n
    if spec.kind == "Box":
        b = np.asarray(spec.b, float)
        c, h = 0.5 * (a + b), 0.5 * (b - a)
        d = x - c
        s = np.where(d >= 0, 1.0, -1.0)
        q = np.abs(d) - h
        qp = np.maximum(q, 0.0)
        out = np.linalg.norm(qp, axis=1)
        n = qp * s / np.maximum(out, 1e-300)[:, None]
        inside = out <= 0
        k = np.argmax(q, axis=1)
        n_in = np.zeros_like(d)
        n_in[np.arange(len(d)), k] = s[np.arange(len(d)), k]
        phi = np.where(inside, q.max(axis=1), out)
        n = np.where(inside[:, None], n_in, n)
        return phi, n
    # Cylinder
    ax = spec.axis
    d = x - a
    ah = d[:, ax]
    r = d.copy()
    r[:, ax] = 0.0
    rho = np.linalg.norm(r, axis=1)
    rhat = r / np.maximum(rho, 1e-300)[:, None]
    e = np.zeros_like(d)
    e[:, ax] = np.where(ah < 0, -1.0, 1.0)
    q0, q1 = rho - spec.radius, np.abs(ah) - spec.half_height
    p0, p1 = np.maximum(q0, 0), np.maximum(q1, 0)
    out = np.hypot(p0, p1)
    n_out = (p0[:, None] * rhat + p1[:, None] * e) / np.maximum(out, 1e-300)[:, None]
    n_in = np.where((q1 > q0)[:, None], e, rhat)
    inside = out <= 0
    return np.where(inside, np.maximum(q0, q1), out), np.where(inside[:, None], n_in, n_out)


def _cross(dim, w, r):
    if dim == 2:
        return np.array([-w[2] * r[1], w[2] * r[0]])
    return np.cross(w, r)


def _moment(dim, r, f):
    if dim == 2:
        return np.array([0.0, 0.0, r[0] * f[1] - r[1] * f[0]])
    return np.cross(r, f)


class Contact:
    __slots__ = ("a", "b", "p", "n", "depth", "e", "mu", "jn", "target", "vb")

    def __init__(self, a, b, p, n, depth, e, mu, vb=None):
        self.a, self.b, self.p, self.n, self.depth, self.e, self.mu = a, b, p, n, depth, e, mu
        self.jn = 0.0
        self.target = 0.0
        self.vb = vb  # b is None: the velocity of the wall or collider surface at p (None: at rest)


def collider_contacts(bodies, pts_local, colliders, t: float, dt: float) -> list[Contact]:
    """Contacts of every body with the scene's colliders (``colliders``: (ColliderSpec, Motion or None)
    pairs, still or in prescribed motion, at their pose at time t): a collider is a body of infinite mass
    moving as prescribed, met like another body (a Sphere body by its centre's distance less its radius,
    others by their sample points; against a Plane by the points that can touch a plane first). The
    friction is the geometric mean of the body's and the collider's, the restitution the body's."""
    dim = bodies[0].dim if bodies else 0
    out = []
    for i, bd in enumerate(bodies):
        R, x, piv = bd.R(), bd.state.x, bd.pivot
        e = bd.cfg.restitution
        for spec, motion in colliders:
            pose = motion.pose(t) if motion is not None else None
            mu = math.sqrt(bd.cfg.friction * spec.friction)
            if bd.spec.kind == "Sphere":
                P = x[None, :]
            else:
                P = (bd.wall_pts if spec.kind == "Plane" else pts_local[i]) - piv
                P = P @ R.T + x
            xb = pose.to_body(P) if pose is not None else P
            phi, nb = sdf_local(spec, xb)
            if bd.spec.kind == "Sphere":
                phi = phi - bd.spec.radius
            n = nb @ pose.R.T if pose is not None else nb
            r = P - x
            if dim == 2:
                vP = bd.state.v + bd.state.w[2] * np.stack([-r[:, 1], r[:, 0]], axis=1)
            else:
                vP = bd.state.v + np.cross(bd.state.w, r)
            vc = pose.velocity_at(P) if pose is not None else np.zeros_like(P)
            margin = (np.linalg.norm(vP - vc, axis=1) + 1e-12) * dt
            for k in np.nonzero(phi < margin)[0]:
                p = P[k] - n[k] * bd.spec.radius if bd.spec.kind == "Sphere" else P[k].copy()
                out.append(Contact(i, None, p, n[k].copy(), -phi[k], e, mu, vc[k].copy()))
    return out


def find_contacts(bodies, pts_local, lo, hi, dt) -> list[Contact]:
    """Contacts of every body with the walls of the domain box [lo, hi] and with every other body.
    ``b`` is None for a wall. A point within one substep's travel of a surface counts (speculative)."""
    dim = len(lo)
    out = []
    poses = [(bd.R(), bd.state.x, bd.pivot) for bd in bodies]
    world_pts = [(P - piv) @ R.T + x for P, (R, x, piv) in zip(pts_local, poses)]
    for i, bd in enumerate(bodies):
        R, x, piv = poses[i]
        P = (bd.wall_pts - piv) @ R.T + x
        r = P - x
        if dim == 2:
            vP = bd.state.v + bd.state.w[2] * np.stack([-r[:, 1], r[:, 0]], axis=1)
        else:
            vP = bd.state.v + np.cross(bd.state.w, r)
        margin = np.abs(vP).max(initial=0.0) * dt
        e, mu = bd.cfg.restitution, bd.cfg.friction
        for ax in range(dim):
            for side, wall in ((1.0, lo[ax]), (-1.0, hi[ax])):
                dist = (P[:, ax] - wall) * side
                if bd.spec.kind == "Sphere":  # exact: the sphere's lowest point
                    c = bd.state.x
                    dmin = (c[ax] - wall) * side - bd.spec.radius
                    if dmin < margin:
                        p = c.copy()
                        p[ax] -= side * bd.spec.radius
                        n = np.zeros(dim)
                        n[ax] = side
                        out.append(Contact(i, None, p, n, -dmin, e, mu))
                    continue
                for k in np.nonzero(dist < margin)[0]:
                    n = np.zeros(dim)
                    n[ax] = side
                    out.append(Contact(i, None, P[k].copy(), n, -dist[k], e, mu))
    for i in range(len(bodies)):
        for j in range(i + 1, len(bodies)):
            A, B = bodies[i], bodies[j]
            reach = np.linalg.norm(B.state.v - A.state.v) * dt + A.reach + B.reach
            if np.linalg.norm(B.state.x - A.state.x) > reach:  # bounding spheres apart: no contact
                continue
            e = max(A.cfg.restitution, B.cfg.restitution)
            mu = math.sqrt(A.cfg.friction * B.cfg.friction)
            if A.spec.kind == "Sphere" and B.spec.kind == "Sphere":
                d = B.state.x - A.state.x
                r = float(np.linalg.norm(d))
                gap = r - A.spec.radius - B.spec.radius
                vrel = np.linalg.norm(B.state.v - A.state.v) * dt
                if gap < vrel and r > 0:
                    n = d / r  # from A to B: the normal on A's side points to B
                    p = A.state.x + n * (A.spec.radius + 0.5 * gap)
                    out.append(Contact(j, i, p, n, -gap, e, mu))  # n points from i (other) to j
                continue
            for s, o in ((i, j), (j, i)):
                S, Ob = bodies[s], bodies[o]
                if S.spec.kind == "Sphere" and Ob.spec.kind != "Sphere":
                    continue  # the sphere is tested by its centre below
                P = world_pts[s]
                Ro, xo, po = poses[o]
                phi, nl = sdf_local(Ob.spec, (P - xo) @ Ro + po)
                vmax = (np.linalg.norm(S.state.v - Ob.state.v) + 1e-12) * dt
                for k in np.nonzero(phi < vmax)[0]:
                    out.append(Contact(s, o, P[k].copy(), Ro @ nl[k], -phi[k], e, mu))
            for s, o in ((i, j), (j, i)):  # a sphere against a non-sphere: its centre's distance less r
                S, Ob = bodies[s], bodies[o]
                if S.spec.kind != "Sphere" or Ob.spec.kind == "Sphere":
                    continue
                Ro, xo, po = poses[o]
                phi, nl = sdf_local(Ob.spec, ((S.state.x - xo) @ Ro + po)[None, :])
                gap = float(phi[0]) - S.spec.radius
                vmax = (np.linalg.norm(S.state.v - Ob.state.v) + 1e-12) * dt
                if gap < vmax:
                    n = Ro @ nl[0]
                    out.append(Contact(s, o, S.state.x - n * S.spec.radius, n, -gap, e, mu))
    return out


def solve_contacts(bodies, contacts: list[Contact], dt: float) -> np.ndarray:
    """Apply the contact impulses to the bodies' velocities (sequential impulses); returns (n, dim + 3) the
    impulse and angular impulse each body received from contacts (for the force output)."""
    dim = bodies[0].dim
    recv = np.zeros((len(bodies), dim + 3))
    if not contacts:
        return recv
    inv = [b.world_inertia_inv() for b in bodies]
    imass = [0.0 if np.all(b.lin_fixed) else 1.0 / b.mass for b in bodies]
    lin_free = [(~b.lin_fixed).astype(float) for b in bodies]
    ang_free = [(~b.ang_fixed).astype(float) for b in bodies]
    v = [b.state.v.copy() for b in bodies]
    w = [b.state.w.copy() for b in bodies]
    xs = [b.state.x for b in bodies]

    def k_term(k, r, d):
        rd = _moment(dim, r, d)
        return imass[k] + float(rd @ (inv[k] @ rd))

    def vel(k, r):
        return v[k] + _cross(dim, w[k], r)

    def apply(k, r, J):
        v[k] += (J / bodies[k].mass) * lin_free[k]
        L = _moment(dim, r, J)
        w[k] += (inv[k] @ L) * ang_free[k]
        recv[k, :dim] += J
        recv[k, dim:] += L

    rows = []
    for c in contacts:
        ra = c.p - xs[c.a]
        rb = c.p - xs[c.b] if c.b is not None else None
        vr = vel(c.a, ra) - (vel(c.b, rb) if rb is not None else (c.vb if c.vb is not None else 0.0))
        vn = float(vr @ c.n)
        if c.depth < 0:  # speculative: an approach up to the gap is allowed within the substep
            target = c.depth / dt
        else:
            target = max(-c.e * vn if vn < -1e-6 else 0.0, ERP * c.depth / dt)
        kn = k_term(c.a, ra, c.n) + (k_term(c.b, rb, c.n) if rb is not None else 0.0)
        vt = vr - vn * c.n
        vt_norm = float(np.linalg.norm(vt))
        t = vt / vt_norm if vt_norm > 1e-12 else None
        kt = (k_term(c.a, ra, t) + (k_term(c.b, rb, t) if rb is not None else 0.0)) if t is not None else 0.0
        rows.append([c, ra, rb, target, kn, t, kt, 0.0, 0.0])
    for _ in range(ITERATIONS):
        for row in rows:
            c, ra, rb, target, kn, t, kt, jn, jt = row
            if kn <= 0:
                continue
            vr = vel(c.a, ra) - (vel(c.b, rb) if rb is not None else (c.vb if c.vb is not None else 0.0))
            vn = float(vr @ c.n)
            jn_new = max(jn + (target - vn) / kn, 0.0)
            J = (jn_new - jn) * c.n
            row[7] = jn_new
            if t is not None and c.mu > 0 and kt > 0:  # friction along the first sliding direction
                jt_new = min(max(jt - float(vr @ t) / kt, -c.mu * jn_new), c.mu * jn_new)
                J = J + (jt_new - jt) * t
                row[8] = jt_new
            apply(c.a, ra, J)
            if rb is not None:
                apply(c.b, rb, -J)
    for k, b in enumerate(bodies):
        b.state.v, b.state.w = v[k], w[k]
    return recv
