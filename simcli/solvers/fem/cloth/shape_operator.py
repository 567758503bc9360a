"""Kirchhoff-Love bending with both curvature invariants: a per-triangle discrete shape operator from
mid-edge normals with one rotation unknown per edge (numpy / scipy, float64).

Per triangle T (rest vertices q0, q1, q2, edge i opposite q_i) the discrete second fundamental form of the
mid-edge formulations of libshell (Chen, Gingold, Vouga et al. 2018, "Physical simulation of
environmentally induced thin shell deformation", ACM TOG 37(4); MidedgeAngle*Formulation, after Grinspun,
Gingold, Reisman and Zorin 2006, "Computing discrete shape operators on general meshes"): the unit normal
field is linear over T and equals, at the midpoint of edge i, the mid-edge normal m_i, perpendicular to
edge i. Its tangential part is s_i t_i (t_i: T's outward in-plane conormal of edge i), and in the basis
e1 = q1 - q0, e2 = q2 - q0

    II = 2 [[(s0 t0 - s1 t1) . e1,  s0 t0 . e2], [s0 t0 . e1,  (s0 t0 - s2 t2) . e2]]   (t0.e1 = t0.e2),

i.e. II = sum_i s_i B_i with constant 2x2 B_i (t_i, e_k of the rest configuration: the difference is the
membrane strain times the curvature, the Kirchhoff-Love inextensible limit). With S = g^-1 (II - II_rest),
g the rest metric, the plate energy

    W_T = A_T D / 2 [nu tr(S)^2 + (1 - nu) tr(S^2)] = A_T D / 2 [(k1 + k2)^2 - 2 (1 - nu) k1 k2]

charges mean AND Gaussian curvature (twist, saddles), which the flat-rest quadratic model of Bergou et al.
2006 does not. Mid-edge normal: the bisector of the two faces rotated about the edge by an unknown phi_e,
so s = theta_e / 2 + sigma phi_e (theta_e the dihedral angle change at the edge, signed by convexity;
sigma = +1 / -1 for the edge's two triangles; small-angle form of libshell's tan / sin expressions, exact
to third order in the per-edge angle), and phi is minimised out: W(theta) = theta^T K theta with
K = A_tt - A_tp A_pp^-1 A_tp^T (A_pp: constant, sparse, well conditioned; factorised once). Why the extra
unknown (measured, tests/unit/test_fem_cloth_shape_operator.py): with the plain bisector (libshell's
MidedgeAverage, phi = 0) a sheet of the Rectangle's criss-cross mesh bent into a cylinder along a diagonal
costs 1.49 times the plate energy and a twist 1.98 times, whatever the resolution; with phi every direction,
the saddle and the twist converge to the plate energy. (A per-triangle fit exact for quadratic surfaces from
the three hinge angles alone is consistent but leaves a zig-zag fold mode free on that mesh: the cantilever
strip came out 1.5 times too soft.)

Free edges: phi_e is free (s = phi_e), so the edge carries no moment (the natural condition). Clamps: a
triangle whose three vertices are pinned is held rigidly; at an edge between it and a free triangle the
mid-edge normal is the held triangle's normal (s = theta_e in the free triangle, no phi): the slope is
prescribed at that edge, and held triangles carry no energy. (With the bisector instead, two pinned rows
clamp half a cell behind the last pinned vertices: a first-order error, 1.9 % in the tip deflection of the
80-cell cantilever.)

Energy, gradient G^T 2 K theta (G: the dihedral angles' gradients, Bridson et al. 2003) and the
Gauss-Newton Hessian: G^T 2 K G is dense, so the model hands the solver the sparse blocks of the Hessian in
(x, phi), [[G^T 2 A_tt G, C^T], [C, 2 A_pp]] with C = 2 A_tp^T G, and the linear solve eliminates phi (the
x part of that solution is the Newton step of the condensed energy). PSD by construction; exact at the rest
state; the omitted term sum_e (2 K theta)_e Hess(theta_e) is the bending moment times the hinge angle's
curvature.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl

from simcli.solvers.fem.cloth.topology import bending_quads, dihedral_angles, dihedral_gradients


def _assemble(Qe, ri, ci, nr, nc):
    """Sum per-triangle 3x3 blocks Qe[t, i, j] into (ri[t, i], ci[t, j]) of an (nr, nc) CSR matrix (negative
    indices dropped)."""
    rows, cols, vals = [], [], []
    for i in range(3):
        for j in range(3):
            sel = (ri[:, i] >= 0) & (ci[:, j] >= 0)
            rows.append(ri[sel, i])
            cols.append(ci[sel, j])
            vals.append(Qe[sel, i, j])
    return sp.coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(nr, nc)
    ).tocsr()


def plate_forms(X: np.ndarray, tris: np.ndarray, D, nu) -> np.ndarray:
    """(m, 3, 3) per triangle: W_T = s^T P_T s for the tangential mid-edge components s (module docstring)."""
    m = len(tris)
    Dt = np.broadcast_to(np.asarray(D, dtype=np.float64), (m,))
    nut = np.broadcast_to(np.asarray(nu, dtype=np.float64), (m,))
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
        t = np.cross(q - p, nh)
        t /= np.linalg.norm(t, axis=1)[:, None]
        return t * np.sign(dot(t, p - opp))[:, None]

    t0, t1, t2 = conormal(q1, q2, q0), conormal(q2, q0, q1), conormal(q0, q1, q2)
    B = np.zeros((m, 3, 2, 2))
    B[:, 0] = 2 * dot(t0, e1)[:, None, None] * np.ones((2, 2))
    B[:, 1, 0, 0] = -2 * dot(t1, e1)
    B[:, 2, 1, 1] = -2 * dot(t2, e2)
    GB = gi[:, None] @ B  # (m, 3, 2, 2): g^-1 B_i
    a = np.trace(GB, axis1=2, axis2=3)  # tr(g^-1 B_i)
    b = np.einsum("kipq,kjqp->kij", GB, GB)  # tr(g^-1 B_i g^-1 B_j)
    return (0.5 * area * Dt)[:, None, None] * (
        nut[:, None, None] * a[:, :, None] * a[:, None, :] + (1 - nut)[:, None, None] * b
    )


def _dihedral_gradients(x: np.ndarray, quads: np.ndarray) -> np.ndarray:

    return dihedral_gradients(x, quads)


class MidedgeBending:
    """Shape-operator bending of one or several stacked triangle meshes (global vertex indices).

    pinned: (n,) bool, the vertices held by the scene (triangles with all three held are clamps)."""

    def __init__(self, X: np.ndarray, tris: np.ndarray, D, nu, pinned=None):
        X = np.asarray(X, dtype=np.float64)
        tris = np.asarray(tris, dtype=np.int64)
        m = len(tris)
        self.n = len(X)
        self.quads = bending_quads(tris)
        k = len(self.quads)
        self.theta0 = dihedral_angles(X, self.quads) if k else np.zeros(0)
        held = np.zeros(m, bool)
        if pinned is not None:
            held = np.asarray(pinned, bool)[tris].all(axis=1)
        # per triangle edge i (opposite vertex i): its hinge (-1 on free edges), the coefficient c of the
        # hinge angle in s (1/2, or 1 next to a held triangle), its edge unknown (-1: none) and sign
        edge_of = {}
        for h, (_, _, a, b) in enumerate(self.quads.tolist()):
            edge_of[(min(a, b), max(a, b))] = h
        tri_of_edge = {}
        for t, (a, b, c) in enumerate(tris.tolist()):
            for p, q in ((b, c), (c, a), (a, b)):
                tri_of_edge.setdefault((min(p, q), max(p, q)), []).append(t)
        hid = np.full((m, 3), -1, np.int64)
        cth = np.zeros((m, 3))
        eid = np.full((m, 3), -1, np.int64)
        sig = np.zeros((m, 3))
        e_of = {}
        for t, (a, b, c) in enumerate(tris.tolist()):
            if held[t]:
                continue
            for i, (p, q) in enumerate(((b, c), (c, a), (a, b))):
                key = (min(p, q), max(p, q))
                h = edge_of.get(key, -1)
                hid[t, i] = h
                clamp = h >= 0 and any(held[o] for o in tri_of_edge[key] if o != t)
                if clamp:
                    cth[t, i] = 1.0
                    continue
                cth[t, i] = 0.5 if h >= 0 else 0.0
                if key in e_of:
                    eid[t, i], sig[t, i] = e_of[key], -1.0
                else:
                    eid[t, i] = e_of[key] = len(e_of)
                    sig[t, i] = 1.0
        ne = len(e_of)
        self.n_edges = ne
        P = plate_forms(X, tris, D, nu)
        P[held] = 0.0
        # s = c theta + sigma phi:  W = theta^T A_tt theta + 2 theta^T A_tp phi + phi^T A_pp phi
        self.Att = _assemble(P * cth[:, :, None] * cth[:, None, :], hid, hid, k, k)
        self.Att = 0.5 * (self.Att + self.Att.T)
        self.Atp = _assemble(P * cth[:, :, None] * sig[:, None, :], hid, eid, k, ne)
        App = _assemble(P * sig[:, :, None] * sig[:, None, :], eid, eid, ne, ne)
        self.App = (0.5 * (App + App.T)).tocsc()
        self._lu = (
            spl.splu(
                self.App, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
            )
            if ne
            else None
        )
        self.aux = None
        # the Hessian's constant factors, doubled once here rather than at every Newton step (exact: x 2)
        self._Att2 = (2 * self.Att).tocsr()
        self._AtpT2 = (2 * self.Atp.T).tocsr()
        self._App2 = 2 * self.App
        # sparsity of G (k x 3n): hinge h touches the 12 dofs of its quad
        self._gr = np.repeat(np.arange(k), 12)
        self._gc = (3 * self.quads[:, :, None] + np.arange(3)).reshape(k, 12).ravel()
        # the value-independent sparsity of G^T 2 A_tt G and 2 A_tp^T G (scipy's products drop exact zeros,
        # e.g. the in-plane parts of a flat hinge's gradient): their values are laid on it (_on_pattern), so
        # the solver's cached Newton-matrix map stays valid while parts of the sheet are flat
        Gs = sp.csr_matrix((np.ones(12 * k), (self._gr, self._gc)), shape=(k, 3 * self.n))
        Hs = (Gs.T @ abs(self._Att2) @ Gs).tocsr()
        Cs = (abs(self._AtpT2) @ Gs).tocsr()
        Hs.sum_duplicates()  # canonical: sorted within rows
        Cs.sum_duplicates()
        self._pat_h = Hs.tocoo()
        self._key_h = self._pat_h.row.astype(np.int64) * (3 * self.n) + self._pat_h.col
        self._pat_c = Cs
        self._key_c = Cs.tocoo().row.astype(np.int64) * (3 * self.n) + Cs.tocoo().col

    def edge_rotations(self, d: np.ndarray) -> np.ndarray:
        """phi* (the minimising mid-edge rotations) for the hinge-angle changes d."""
        if self._lu is None:
            return np.zeros(0)
        return -self._lu.solve(np.asarray(self.Atp.T @ d))

    def angles(self, x: np.ndarray) -> np.ndarray:
        d = dihedral_angles(x, self.quads) - self.theta0
        return (d + np.pi) % (2 * np.pi) - np.pi

    def _moment(self, d: np.ndarray) -> np.ndarray:
        """K d = (1/2) dW/dtheta."""
        Kd = self.Att @ d
        if self._lu is not None:
            Kd = Kd + self.Atp @ self.edge_rotations(d)
        return Kd

    def energy(self, x: np.ndarray) -> float:
        if not len(self.quads):
            return 0.0
        d = self.angles(x)
        return float(d @ self._moment(d))

    def __call__(self, x: np.ndarray, order: int = 2):
        """Energy, gradient (n, 3) and, for order 2, the x block of the Gauss-Newton Hessian as COO
        (rows, cols, vals); then self.aux = (C, 2 A_pp), the blocks coupling the edge unknowns."""
        k = len(self.quads)
        if not k:
            self.aux = None
            return 0.0, np.zeros_like(x), (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
        d = self.angles(x)
        Kd = self._moment(d)
        energy = float(d @ Kd)
        if order < 1:  # energy only
            return energy, None, None
        g = _dihedral_gradients(x, self.quads)  # (k, 4, 3)
        ge = (2 * Kd)[:, None, None] * g
        grad = np.zeros_like(x)
        for a in range(4):
            np.add.at(grad, self.quads[:, a], ge[:, a])
        if order < 2:
            return energy, grad, None
        G = sp.csr_matrix((g.reshape(-1), (self._gr, self._gc)), shape=(k, 3 * len(x)))
        H = (G.T @ self._Att2 @ G).tocsr()
        hv = self._on_pattern(H, self._key_h)
        if self._lu is not None:
            C = (self._AtpT2 @ G).tocsr()
            Cp = self._pat_c.copy()
            Cp.data = self._on_pattern(C, self._key_c)
            self.aux = (Cp, self._App2)
        else:
            self.aux = None
        ph = self._pat_h
        return energy, grad, (ph.row.astype(np.int64), ph.col.astype(np.int64), hv)

    def _on_pattern(self, A, key):
        """The values of the canonical CSR A laid on the (row-major sorted) structural pattern key (a
        superset of A's): exact zeros A dropped are 0 there."""
        A.sum_duplicates()
        if A.nnz == len(key):
            return A.data
        ak = np.repeat(np.arange(A.shape[0], dtype=np.int64), np.diff(A.indptr)) * A.shape[1] + A.indices
        out = np.zeros(len(key))
        out[np.searchsorted(key, ak)] = A.data
        return out

    def condensed_hessian(self, x: np.ndarray) -> np.ndarray:
        """Dense Gauss-Newton Hessian G^T 2 K G of the condensed energy (tests, small meshes)."""
        r, c, v = self(x, 2)[2]
        H = sp.coo_matrix((v, (r, c)), shape=(x.size, x.size)).toarray()
        if self.aux is not None:
            C, A = self.aux
            H -= C.T @ spl.spsolve(A.tocsc(), C.toarray())
        return H
