"""Kirchhoff-Love bending with both curvature invariants: a per-triangle discrete shape operator from
mid-edge normals (numpy, vectorised, float64).

Per triangle T (rest vertices q0, q1, q2, edge i opposite q_i) the discrete second fundamental form of the
mid-edge-average formulation of libshell (Chen, Gingold, Vouga et al. 2018, "Physical simulation of
environmentally induced thin shell deformation", ACM TOG 37(4); MidedgeAverageFormulation, after
Grinspun, Gingold, Reisman and Zorin 2006, "Computing discrete shape operators on general meshes"):
the unit normal field is linear over T, equal at the midpoint of edge i to the mid-edge normal
m_i = normalise(n_T + n_i) (n_i: the normal of the neighbour across edge i). m_i is perpendicular to edge i,
so its tangential part is s_i t_i, t_i the outward in-plane conormal of edge i and s_i = sin(theta_i / 2)
with theta_i the dihedral angle at edge i (signed by convexity, the same seen from both sides). In the
basis e1 = q1 - q0, e2 = q2 - q0,

    II = 2 [[(s0 t0 - s1 t1) . e1,  s0 t0 . e2], [s0 t0 . e1,  (s0 t0 - s2 t2) . e2]]   (t0.e1 = t0.e2),

i.e. II = sum_i s_i B_i with constant 2x2 B_i when t_i and e_k are taken in the rest configuration (the
difference is of the order of the membrane strain times the curvature: Kirchhoff-Love, inextensible
limit). With S = g^-1 (II - II_rest) (g the rest first fundamental form) the plate energy

    W_T = A_T D / 2 [nu tr(S)^2 + (1 - nu) tr(S^2)] = A_T D / 2 [(k1 + k2)^2 - 2 (1 - nu) k1 k2]

charges mean AND Gaussian curvature (twist, saddles), which the flat-rest quadratic model of Bergou et al.
2006 cannot. s_i is replaced by theta_i / 2 (same to third order; per-edge angles on a refined mesh are
small), so W = sum_T (theta_T - theta0_T)^T Q_T (theta_T - theta0_T) with a constant 3x3 PSD Q_T per triangle:
a quadratic form in the hinge angles, rotation invariant, with gradient G^T 2 Q (theta - theta0) (G: the
dihedral angles' gradients, Bridson et al. 2003). Hessian: Gauss-Newton G^T 2 Q G (PSD by construction;
exact at the rest state; the omitted term sum_e (2 Q dtheta)_e Hess(theta_e) is of the order of the
curvature change times the hinge's angle sensitivity). Free edges: no neighbour, the mid-edge normal is
the face normal, s = 0 (libshell's convention): the moment-free edge condition of the plate in the
direction normal to the edge. A clamp is modelled by pinning two rows of vertices (the triangles next to
the clamp keep flat neighbours).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from simcli.solvers.fem.cloth.topology import bending_quads, dihedral_angles


def _dihedral_gradients(x: np.ndarray, quads: np.ndarray) -> np.ndarray:
    from simcli.solvers.fem.cloth.model import dihedral_gradients

    return dihedral_gradients(x, quads)


class MidedgeBending:
    """Shape-operator bending of one or several stacked triangle meshes (global vertex indices)."""

    def __init__(self, X: np.ndarray, tris: np.ndarray, D, nu):
        X = np.asarray(X, dtype=np.float64)
        tris = np.asarray(tris, dtype=np.int64)
        m = len(tris)
        Dt = np.broadcast_to(np.asarray(D, dtype=np.float64), (m,))
        nut = np.broadcast_to(np.asarray(nu, dtype=np.float64), (m,))
        self.n = len(X)
        self.quads = bending_quads(tris)
        k = len(self.quads)
        self.theta0 = dihedral_angles(X, self.quads) if k else np.zeros(0)
        # hinge index of each triangle edge i (opposite vertex i), -1 on free edges
        edge_of = {}
        for h, (_, _, a, b) in enumerate(self.quads.tolist()):
            edge_of[(min(a, b), max(a, b))] = h
        hid = np.full((m, 3), -1, np.int64)
        for t, (a, b, c) in enumerate(tris.tolist()):
            for i, (p, q) in enumerate(((b, c), (c, a), (a, b))):
                hid[t, i] = edge_of.get((min(p, q), max(p, q)), -1)
        # rest geometry per triangle
        q0, q1, q2 = (X[tris[:, a]] for a in range(3))
        e1, e2 = q1 - q0, q2 - q0
        nrm = np.cross(e1, e2)
        area = 0.5 * np.linalg.norm(nrm, axis=1)
        nh = nrm / (2 * area)[:, None]
        dot = lambda a, b: np.einsum("ij,ij->i", a, b)  # noqa: E731
        g = np.empty((m, 2, 2))
        g[:, 0, 0], g[:, 0, 1], g[:, 1, 1] = dot(e1, e1), dot(e1, e2), dot(e2, e2)
        g[:, 1, 0] = g[:, 0, 1]
        gi = np.linalg.inv(g)

        def conormal(p, q, opp):  # outward in-plane unit normal of edge (p, q), away from opp
            ed = q - p
            t = np.cross(ed, nh)
            t /= np.linalg.norm(t, axis=1)[:, None]
            s = np.sign(dot(t, p - opp))
            return t * s[:, None]

        t0, t1, t2 = conormal(q1, q2, q0), conormal(q2, q0, q1), conormal(q0, q1, q2)
        B = np.zeros((m, 3, 2, 2))
        B[:, 0] = 2 * dot(t0, e1)[:, None, None] * np.ones((2, 2))
        B[:, 1, 0, 0] = -2 * dot(t1, e1)
        B[:, 2, 1, 1] = -2 * dot(t2, e2)
        GB = gi[:, None] @ B  # (m, 3, 2, 2): g^-1 B_i
        a = np.trace(GB, axis1=2, axis2=3)  # (m, 3)
        b = np.einsum("kipq,kjqp->kij", GB, GB)  # tr(g^-1 B_i g^-1 B_j)
        # s_i = theta_i / 2: W_T = sum_ij theta_i theta_j (A D / 8) [nu a_i a_j + (1 - nu) b_ij]
        Q = (area * Dt / 8.0)[:, None, None] * (
            nut[:, None, None] * a[:, :, None] * a[:, None, :] + (1 - nut)[:, None, None] * b
        )
        ok = hid >= 0
        rows, cols, vals = [], [], []
        for i in range(3):
            for j in range(3):
                sel = ok[:, i] & ok[:, j]
                rows.append(hid[sel, i])
                cols.append(hid[sel, j])
                vals.append(Q[sel, i, j])
        self.Q = sp.coo_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(k, k)
        ).tocsr()
        self.Q = 0.5 * (self.Q + self.Q.T)
        self.hinge_of_tri = hid
        self.area = area
        # sparsity of G (k x 3n): hinge h touches the 12 dofs of its quad
        self._gr = np.repeat(np.arange(k), 12)
        self._gc = (3 * self.quads[:, :, None] + np.arange(3)).reshape(k, 12).ravel()

    def angles(self, x: np.ndarray) -> np.ndarray:
        d = dihedral_angles(x, self.quads) - self.theta0
        return (d + np.pi) % (2 * np.pi) - np.pi

    def energy(self, x: np.ndarray) -> float:
        if not len(self.quads):
            return 0.0
        d = self.angles(x)
        return float(d @ (self.Q @ d))

    def __call__(self, x: np.ndarray, order: int = 2):
        """Energy, gradient (n, 3) and, for order 2, the Gauss-Newton Hessian as COO (rows, cols, vals)."""
        k = len(self.quads)
        if not k:
            return 0.0, np.zeros_like(x), (np.zeros(0, np.int64),) * 2 + (np.zeros(0),)
        d = self.angles(x)
        Qd = self.Q @ d
        energy = float(d @ Qd)
        g = _dihedral_gradients(x, self.quads)  # (k, 4, 3)
        ge = (2 * Qd)[:, None, None] * g
        grad = np.zeros_like(x)
        for a in range(4):
            np.add.at(grad, self.quads[:, a], ge[:, a])
        if order < 2:
            return energy, grad, None
        G = sp.csr_matrix((g.reshape(-1), (self._gr, self._gc)), shape=(k, 3 * len(x)))
        H = (G.T @ (2 * self.Q) @ G).tocoo()
        return energy, grad, (H.row.astype(np.int64), H.col.astype(np.int64), H.data)
