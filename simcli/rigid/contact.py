"""Rigid-wall and rigid-rigid contact on the host (numpy): sequential velocity impulses.

Each body's surface is represented by sample points in its body frame (a Box: its corners, edge and face
points; a Sphere: exact against planes and spheres, points otherwise; a Cylinder: points on its rims and
caps). A contact is a sample point of one body inside (or, within the substep, reaching) the domain's walls
or another body's signed distance; a pair of spheres is exact. Each contact gets a normal impulse that
removes the approaching normal velocity (restitution e: reverses e of it; a penetration is pushed out at
ERP of its depth per substep), and a Coulomb friction impulse of at most mu times it, applied to both bodies
(equal and opposite: momentum is conserved between bodies); a few Gauss-Seidel sweeps over the contacts.
"""

from __future__ import annotations

import math

import numpy as np

ITERATIONS = 8
ERP = 0.2  # share of a penetration depth removed per substep (Baumgarte)


def surface_points(spec, dim: int, n: int = 4) -> np.ndarray:
    """Sample points (k, dim) on a body's surface in its body frame."""
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


def sdf_local(spec, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(phi (k,), outward normal (k, dim)) of a body-frame shape at body-frame points x (k, dim)."""
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
    __slots__ = ("a", "b", "p", "n", "depth", "e", "mu", "jn", "target")

    def __init__(self, a, b, p, n, depth, e, mu):
        self.a, self.b, self.p, self.n, self.depth, self.e, self.mu = a, b, p, n, depth, e, mu
        self.jn = 0.0
        self.target = 0.0


def find_contacts(bodies, pts_local, lo, hi, dt) -> list[Contact]:
    """Contacts of every body with the walls of the domain box [lo, hi] and with every other body.
    ``b`` is None for a wall. A point within one substep's travel of a surface counts (speculative)."""
    dim = len(lo)
    out = []
    poses = [(bd.R(), bd.state.x, bd.pivot) for bd in bodies]
    world_pts = [(P - piv) @ R.T + x for P, (R, x, piv) in zip(pts_local, poses)]
    for i, bd in enumerate(bodies):
        P = world_pts[i]
        vP = bd.state.v + np.array([_cross(dim, bd.state.w, r) for r in (P - bd.state.x)])
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
    if not contacts:
        return np.zeros((len(bodies), 0))
    dim = bodies[0].dim
    recv = np.zeros((len(bodies), dim + 3))
    inv = [b.world_inertia_inv() for b in bodies]

    def inv_mass(b):
        return 0.0 if np.all(b.lin_fixed) else 1.0 / b.mass

    def vel_at(k, p):
        b = bodies[k]
        return b.state.v + _cross(dim, b.state.w, p - b.state.x)

    def apply(k, p, J):
        b = bodies[k]
        dv = J / b.mass
        dv[b.lin_fixed] = 0.0
        b.state.v = b.state.v + dv
        L = _moment(dim, p - b.state.x, J)
        dw = inv[k] @ L
        dw[b.ang_fixed] = 0.0
        b.state.w = b.state.w + dw
        recv[k, :dim] += J
        recv[k, dim:] += L

    def k_term(k, p, n):
        b = bodies[k]
        r = p - b.state.x
        rn = _moment(dim, r, n)
        return inv_mass(b) + float(rn @ (inv[k] @ rn))

    for c in contacts:
        vr = vel_at(c.a, c.p) - (vel_at(c.b, c.p) if c.b is not None else 0.0)
        vn = float(vr @ c.n)
        bias = ERP * max(c.depth, 0.0) / dt
        c.target = max(-c.e * vn if vn < -1e-6 else 0.0, bias)
        if c.depth < 0:  # speculative: allow it to close the gap within the substep
            c.target = c.depth / dt  # negative: an approach up to the gap is allowed
    for _ in range(ITERATIONS):
        for c in contacts:
            vr = vel_at(c.a, c.p) - (vel_at(c.b, c.p) if c.b is not None else 0.0)
            vn = float(vr @ c.n)
            kn = k_term(c.a, c.p, c.n) + (k_term(c.b, c.p, c.n) if c.b is not None else 0.0)
            if kn <= 0:
                continue
            dj = (c.target - vn) / kn
            jn_new = max(c.jn + dj, 0.0)
            dj = jn_new - c.jn
            c.jn = jn_new
            J = dj * c.n
            # friction on the tangential relative velocity, at most mu jn
            vt = vr - vn * c.n
            vt_norm = float(np.linalg.norm(vt))
            if c.mu > 0 and vt_norm > 1e-12:
                t = vt / vt_norm
                kt = k_term(c.a, c.p, t) + (k_term(c.b, c.p, t) if c.b is not None else 0.0)
                jt = min(vt_norm / kt, c.mu * max(dj, 0.0)) if kt > 0 else 0.0
                J = J - jt * t
            apply(c.a, c.p, J)
            if c.b is not None:
                apply(c.b, c.p, -J)
    return recv
