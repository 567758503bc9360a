"""Elastic energy of a thin shell on a triangle mesh (numpy, vectorised, float64).

Membrane (per triangle, plane stress): the deformation gradient F = Ds Bm (3x2) maps the triangle's rest
2D frame to space, Green strain E = (F^T F - I) / 2, St Venant-Kirchhoff energy density
psi = mu |E|^2 + lambda_ps / 2 tr(E)^2 with the plane-stress lambda_ps = E nu / (1 - nu^2), times the rest
area and thickness. Valid for large rotations and moderate strains; its Hessian is projected to be
positive semi-definite per triangle (eigenvalues of dP/dF clamped at 0).

Bending: by default (material bending_model: shape_operator) the Kirchhoff-Love plate energy with both
curvature invariants from a discrete shape operator, simcli.solvers.fem.cloth.shape_operator (ShellModel's
`shape`, on the triangles that use it). The older model (bending_model: quadratic), two discretisations of
the mean-curvature energy D/2 int (2H)^2 dA (cylinder of radius R: D / (2 R^2) per unit area), chosen by
the rest shape:
- flat rest mesh (Rectangle, planar Mesh): the quadratic model of Bergou, Wardetzky, Harmon, Zorin and
  Grinspun 2006 ("A quadratic bending model for inextensible surfaces"), vertex form
  W = D/2 sum_v |(K x)_v|^2 / A_v, K x = L x + the free edges' flux: L the cotangent Laplacian of the rest
  mesh, A_v the Voronoi area, and at a free edge e of triangle T the term (|e| / 2) F_T nu0 for each of its
  vertices (nu0 the rest outward conormal, F_T the triangle's deformation gradient, linear in x), so that
  (K x)_v / A_v is the mean-curvature normal 2 H n on boundary vertices too. Linear in x: rotation
  invariant (K X = 0 for the flat rest, K R x = R K x), constant Hessian D K^T A^-1 K.
- curved rest mesh: discrete-shell hinges (Grinspun, Hirani, Desbrun and Schroeder 2003)
  W = sum_e k_e (theta - theta0)^2, k_e = D |e0|^2 / (A1 + A2), rest dihedral angles theta0 (exact plate
  energy on equilateral meshes; on right-triangle meshes 2 to 3 times stiffer depending on direction,
  which is why flat sheets use the quadratic model). Gauss-Newton Hessian 2 k_e grad theta grad theta^T.
"""

from __future__ import annotations

import numpy as np

from simcli.solvers.fem.cloth.topology import bending_quads, dihedral_angles, dihedral_gradients


def triangle_areas(x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(
        np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]), axis=1
    )


def mesh_problems(x: np.ndarray, tris: np.ndarray) -> list[str]:
    """Why a triangle mesh cannot be a cloth: degenerate triangles, edges of more than two triangles,
    repeated vertex indices (with the first location of each)."""
    out = []
    bad = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    area = triangle_areas(x, tris)
    scale = max(float(np.ptp(x, axis=0).max()), 1e-300)
    bad |= area <= 1e-12 * scale**2
    if bad.any():
        k = int(np.nonzero(bad)[0][0])
        out.append(
            f"{int(bad.sum())} degenerate triangle(s) (zero area), the first #{k} at "
            f"{np.round(x[tris[k]].mean(axis=0), 6).tolist()}"
        )
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    uniq, cnt = np.unique(e, axis=0, return_counts=True)
    if (cnt > 2).any():
        k = int(np.nonzero(cnt > 2)[0][0])
        out.append(
            f"{int((cnt > 2).sum())} non-manifold edge(s) (shared by more than two triangles), the first "
            f"between {np.round(x[uniq[k, 0]], 6).tolist()} and {np.round(x[uniq[k, 1]], 6).tolist()}"
        )
    return out


class ShellModel:
    """Rest state and elastic energy of one or several triangle meshes stacked (global vertex indices)."""

    def __init__(
        self,
        X: np.ndarray,
        tris: np.ndarray,
        mu,
        lam_ps,
        thickness,
        D,
        tri_body=None,
        shape_operator=None,
        pinned=None,
    ):
        """shape_operator: per triangle (bool) or None: triangles whose bending is the shape-operator model
        (simcli.solvers.fem.cloth.shape_operator, both curvature invariants) instead of the quadratic /
        hinge model below; pinned: (n,) bool, held vertices (held triangles clamp that model)."""
        self.X = np.asarray(X, dtype=np.float64)
        self.tris = np.asarray(tris, dtype=np.int64)
        m = len(self.tris)
        as_arr = lambda v: np.broadcast_to(np.asarray(v, dtype=np.float64), (m,)).copy()  # noqa: E731
        self.mu, self.lam, self.h = as_arr(mu), as_arr(lam_ps), as_arr(thickness)
        x0, x1, x2 = (self.X[self.tris[:, k]] for k in range(3))
        e1 = x1 - x0
        l1 = np.linalg.norm(e1, axis=1)
        u = e1 / l1[:, None]
        nrm = np.cross(e1, x2 - x0)
        self.area = 0.5 * np.linalg.norm(nrm, axis=1)
        v = np.cross(nrm / (2 * self.area)[:, None], u)
        Dm = np.zeros((m, 2, 2))
        Dm[:, 0, 0] = l1
        Dm[:, 0, 1] = np.einsum("ij,ij->i", x2 - x0, u)
        Dm[:, 1, 1] = np.einsum("ij,ij->i", x2 - x0, v)
        self.Bm = np.linalg.inv(Dm)  # (m, 2, 2)
        B = self.Bm
        # dF_ij / dx_{a,i} = G[a, j]: vertex 0 gets minus the sum of the rows of Bm
        self.G = np.stack([-(B[:, 0, :] + B[:, 1, :]), B[:, 0, :], B[:, 1, :]], axis=1)  # (m, 3, 2)
        # bending hinges
        self.quads = bending_quads(self.tris)
        self.theta0 = dihedral_angles(self.X, self.quads)
        Dq = np.broadcast_to(np.asarray(D, dtype=np.float64), (m,))
        self.shape = None
        so = np.zeros(m, bool)
        if shape_operator is not None:  # (bending_stiffness 0: no bending at all, either model)
            so = np.broadcast_to(np.asarray(shape_operator, dtype=bool), (m,)) & (Dq > 0)
        if so.any():
            from simcli.solvers.fem.cloth.shape_operator import MidedgeBending

            nu = self.lam / np.maximum(self.lam + 2 * self.mu, 1e-300)  # plane stress: lam / (lam + 2 mu)
            self.shape = MidedgeBending(self.X, self.tris[so], Dq[so], nu[so], pinned)
            Dq = np.where(so, 0.0, Dq)
            if so.all():
                self.quads = np.zeros((0, 4), np.int64)
                self.theta0 = np.zeros(0)
        if len(self.quads):
            # the two triangles of each hinge: look them up by their vertex sets
            key = {tuple(sorted(t)): i for i, t in enumerate(self.tris.tolist())}
            q = self.quads
            t1 = np.array([key[tuple(sorted(r))] for r in q[:, [0, 2, 3]].tolist()])
            t2 = np.array([key[tuple(sorted(r))] for r in q[:, [1, 2, 3]].tolist()])
            le = np.linalg.norm(self.X[q[:, 3]] - self.X[q[:, 2]], axis=1)
            self.kb = 0.5 * (Dq[t1] + Dq[t2]) * le**2 / (self.area[t1] + self.area[t2])
        else:
            self.kb = np.zeros(0)
        self.quadratic = None
        if len(self.quads) and np.all(np.abs(self.theta0) < 1e-6):
            self.quadratic = quadratic_bending(self.X, self.tris, Dq)
            self.quads = np.zeros((0, 4), np.int64)
            self.theta0 = np.zeros(0)
            self.kb = np.zeros(0)
        # sparsity pattern of the Hessian blocks (rows/cols of the 9x9 and 12x12 element matrices)
        dof_t = (3 * self.tris[:, :, None] + np.arange(3)).reshape(m, 9)
        self._rows_t = np.repeat(dof_t, 9, axis=1).ravel()
        self._cols_t = np.tile(dof_t, (1, 9)).ravel()
        k = len(self.quads)
        dof_q = (3 * self.quads[:, :, None] + np.arange(3)).reshape(k, 12)
        self._rows_q = np.repeat(dof_q, 12, axis=1).ravel()
        self._cols_q = np.tile(dof_q, (1, 12)).ravel()

    @property
    def aux(self):
        """Hessian blocks of the bending model's edge unknowns from the last order-2 evaluation, or None."""
        return self.shape.aux if self.shape is not None else None

    # ------------------------------------------------------------ membrane
    def deformation(self, x: np.ndarray) -> np.ndarray:
        t = self.tris
        Ds = np.stack([x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]]], axis=2)  # (m, 3, 2)
        return Ds @ self.Bm

    def green_strain(self, x: np.ndarray) -> np.ndarray:
        F = self.deformation(x)
        return 0.5 * (np.swapaxes(F, 1, 2) @ F - np.eye(2))

    def stress(self, x: np.ndarray) -> np.ndarray:
        """Second Piola-Kirchhoff membrane stress S [Pa] (m, 2, 2) in each triangle's rest frame."""
        Eg = self.green_strain(x)
        tr = Eg[:, 0, 0] + Eg[:, 1, 1]
        return 2 * self.mu[:, None, None] * Eg + (self.lam * tr)[:, None, None] * np.eye(2)

    def membrane(self, x: np.ndarray, order: int = 2, inertia: np.ndarray | None = None):
        """Energy [J], gradient (n, 3) and, for order 2, the projected element Hessians (m, 9, 9).

        inertia (n,), optional: each vertex's inertia term of the Newton matrix (M / dt^2 + c M / dt) divided
        among its triangles. A compressed triangle's Hessian H_e is then projected as
        proj(H_e + D_e) - D_e, D_e its vertices' shares: the assembled matrix (which adds M / dt^2 + c M / dt
        back) stays positive semi-definite, and the negative curvature of a compressed triangle is kept as far
        as its inertia covers it, where clamping dP/dF drops all of it (docs/FEM.md, Newton on compressed
        triangles). Without it: dP/dF clamped (6 x 6)."""
        F = self.deformation(x)
        Eg = 0.5 * (np.swapaxes(F, 1, 2) @ F - np.eye(2))
        tr = Eg[:, 0, 0] + Eg[:, 1, 1]
        mu, lam = self.mu[:, None, None], self.lam[:, None, None]
        S = 2 * mu * Eg + lam * tr[:, None, None] * np.eye(2)
        w = self.area * self.h  # rest volume
        psi = self.mu * np.einsum("kij,kij->k", Eg, Eg) + 0.5 * self.lam * tr**2
        energy = float(np.sum(w * psi))
        if order < 1:  # energy only (the line search's trials)
            return energy, None, None
        P = F @ S  # (m, 3, 2)
        # grad_{a,i} = w sum_j P_ij G_aj
        ge = w[:, None, None] * np.einsum("kij,kaj->kai", P, self.G)  # (m, 3 vertices, 3)
        grad = np.zeros_like(x)
        for a in range(3):
            np.add.at(grad, self.tris[:, a], ge[:, a])
        if order < 2:
            return energy, grad, None
        m = len(F)
        dPdF = np.empty((m, 6, 6))
        for c in range(6):
            dF = np.zeros((m, 3, 2))
            dF[:, c // 2, c % 2] = 1.0
            FtdF = np.swapaxes(F, 1, 2) @ dF
            dE = 0.5 * (FtdF + np.swapaxes(FtdF, 1, 2))
            trd = dE[:, 0, 0] + dE[:, 1, 1]
            dS = 2 * mu * dE + lam * trd[:, None, None] * np.eye(2)
            dP = dF @ S + F @ dS
            dPdF[:, :, c] = dP.reshape(m, 6)
        dPdF = 0.5 * (dPdF + np.swapaxes(dPdF, 1, 2))
        # dF : dP = tr(dF^T dF S) + dE : C : dE; the second term is never negative (mu > 0, lambda >= 0)
        # and the first is not where S is positive semi-definite (smaller eigenvalue of the 2x2 S >= 0):
        # there dP/dF is already PSD, and only the compressed triangles need the eigen-projection
        half_tr = 0.5 * (S[:, 0, 0] + S[:, 1, 1])
        s_min = half_tr - np.hypot(0.5 * (S[:, 0, 0] - S[:, 1, 1]), S[:, 0, 1])
        comp = np.nonzero(s_min < 0.0)[0]
        if len(comp) and inertia is None:
            lam_e, Q = np.linalg.eigh(dPdF[comp])
            dPdF[comp] = (Q * np.maximum(lam_e, 0.0)[:, None, :]) @ np.swapaxes(Q, 1, 2)
        # dF_(ij) / dx_(a,l) = G[a, j] delta_il  ->  (m, 6, 9)
        J = np.zeros((m, 3, 2, 3, 3))
        for i in range(3):
            J[:, i, :, :, i] = np.swapaxes(self.G, 1, 2)  # [k, j, a]
        J = J.reshape(m, 6, 9)
        H = w[:, None, None] * (np.swapaxes(J, 1, 2) @ dPdF @ J)
        if len(comp) and inertia is not None:
            De = np.repeat(inertia[self.tris[comp]], 3, axis=1)[:, :, None] * np.eye(9)  # (c, 9, 9)
            lam_e, Q = np.linalg.eigh(H[comp] + De)
            H[comp] = (Q * np.maximum(lam_e, 0.0)[:, None, :]) @ np.swapaxes(Q, 1, 2) - De
        return energy, grad, H

    # ------------------------------------------------------------ bending
    def bending(self, x: np.ndarray, order: int = 2):
        if not len(self.quads):
            return 0.0, (np.zeros_like(x) if order >= 1 else None), None
        th = dihedral_angles(x, self.quads)
        d = th - self.theta0
        d = (d + np.pi) % (2 * np.pi) - np.pi  # across the +-pi cut
        energy = float(np.sum(self.kb * d**2))
        if order < 1:
            return energy, None, None
        g = dihedral_gradients(x, self.quads)  # (k, 4, 3)
        ge = (2 * self.kb * d)[:, None, None] * g
        grad = np.zeros_like(x)
        for a in range(4):
            np.add.at(grad, self.quads[:, a], ge[:, a])
        if order < 2:
            return energy, grad, None
        gf = g.reshape(-1, 12)
        H = (2 * self.kb)[:, None, None] * gf[:, :, None] * gf[:, None, :]
        return energy, grad, H

    def energy_grad_hess(self, x: np.ndarray, order: int = 2, inertia: np.ndarray | None = None):
        """Total elastic energy, gradient (n, 3) and the Hessian as COO triplets (rows, cols, values);
        inertia: see membrane."""
        em, gm, Hm = self.membrane(x, order, inertia)
        eb, gb, Hb = self.bending(x, order)
        if self.quadratic is not None:
            Q = self.quadratic  # scalar (n, n) matrix acting on each coordinate
            Qx = Q @ x
            eb += 0.5 * float(np.sum(x * Qx))
            if order >= 1:
                gb = gb + Qx
        if self.shape is not None:
            es, gs, Hs = self.shape(x, order)
            eb += es
            if order >= 1:
                gb = gb + gs
        if order < 1:  # energy only
            return em + eb, None, None
        if order < 2:
            return em + eb, gm + gb, None
        rows = [self._rows_t, self._rows_q]
        cols = [self._cols_t, self._cols_q]
        vals = [Hm.ravel(), Hb.ravel() if Hb is not None else np.zeros(0)]
        if self.shape is not None:
            rows.append(Hs[0])
            cols.append(Hs[1])
            vals.append(Hs[2])
        if self.quadratic is not None:
            Qc = self.quadratic.tocoo()
            for k in range(3):
                rows.append(3 * Qc.row + k)
                cols.append(3 * Qc.col + k)
                vals.append(Qc.data)
        return em + eb, gm + gb, (np.concatenate(rows), np.concatenate(cols), np.concatenate(vals))


def quadratic_bending(X: np.ndarray, tris: np.ndarray, D: np.ndarray):
    """D K^T A^-1 K (module docstring): scipy CSR (n, n)."""
    import scipy.sparse as sp

    n = len(X)
    rows, cols, vals = [], [], []
    area = np.zeros(n)
    Dv = np.zeros(n)
    wsum = np.zeros(n)

    def cot(p, q, r):  # cotangent of the angle at p in triangle (p, q, r)
        u, v = X[q] - X[p], X[r] - X[p]
        return np.einsum("ij,ij->i", u, v) / np.linalg.norm(np.cross(u, v), axis=1)

    for a in range(3):
        i, j, k = tris[:, a], tris[:, (a + 1) % 3], tris[:, (a + 2) % 3]
        c = 0.5 * cot(i, j, k)  # weight of the opposite edge (j, k)
        rows += [j, k, j, k]
        cols += [k, j, j, k]
        vals += [c, c, -c, -c]
        # Voronoi area (Meyer et al. 2003; the Rectangle's triangles are not obtuse)
        va = (np.sum((X[j] - X[i]) ** 2, 1) * cot(k, i, j) + np.sum((X[k] - X[i]) ** 2, 1) * cot(j, k, i)) / 8
        va = np.maximum(va, 0.0)
        np.add.at(area, i, va)
        np.add.at(Dv, i, D * va)
        np.add.at(wsum, i, va)
    # free edges: the flux (|e| / 2) dx/dnu of each boundary edge into its two vertices, with the outward
    # conormal's image F nu0 = sum_a x_a (grad phi_a . nu0) in the edge's triangle (linear in x)
    he = np.concatenate([tris[:, [0, 1, 2]], tris[:, [1, 2, 0]], tris[:, [2, 0, 1]]])
    tri_of = np.tile(np.arange(len(tris)), 3)
    key = np.sort(he[:, :2], axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    bnd = cnt[inv.ravel()] == 1
    for (a, b, c), t in zip(he[bnd], tri_of[bnd]):
        xa, xb, xc = X[a], X[b], X[c]
        ed = xb - xa
        le = float(np.linalg.norm(ed))
        w_ = xc - xa
        perp = w_ - (w_ @ ed) / (le * le) * ed
        nu0 = -perp / np.linalg.norm(perp)  # outward, in the rest plane
        coef = {}
        for v, (p_, q_) in ((a, (b, c)), (b, (c, a)), (c, (a, b))):  # grad phi_v: from edge (p, q) to v
            e2 = X[q_] - X[p_]
            w2 = X[v] - X[p_]
            pp = w2 - (w2 @ e2) / (e2 @ e2) * e2
            coef[v] = float((pp / (pp @ pp)) @ nu0)
        for r_ in (a, b):
            for v in (a, b, c):
                rows.append(np.array([r_]))
                cols.append(np.array([v]))
                vals.append(np.array([0.5 * le * coef[v]]))
    K = sp.coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    ).tocsr()
    w = np.where(area > 0, Dv / np.maximum(wsum, 1e-300) / np.maximum(area, 1e-300), 0.0)
    return (K.T @ sp.diags(w) @ K).tocsr()
