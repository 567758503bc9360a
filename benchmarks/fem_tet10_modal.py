"""Modal check of quadratic tetrahedra (docs/FEM.md, Elements): the cantilever of
configs/validation/fem_cantilever_tet10_freq.yaml (L = 1 m, 0.1 x 0.1 m, E = 1e8 Pa, nu = 0.3, rho = 1000,
clamped at x = 0) meshed as simcli meshes it (Kuhn-split box, edge nodes from simcli.solvers.fem.tet10),
linear elasticity assembled in numpy with the 4-point rule, and the lowest generalised eigenvalues with
the HRZ lumped mass simcli uses and with the consistent mass (exact quartic integrals). Independent of the
Taichi solver: the dynamic measurement (verify case fem_cantilever_tet10_freq) should match the HRZ
column's vertical mode; HRZ against consistent is what the lumping does to the frequency.

Usage: python benchmarks/fem_tet10_modal.py RESOLUTION   (10, 20, 40; 40 takes about a minute)
Measured 2026-11-26 (the two bending modes, y and z, differ slightly on the Kuhn mesh):
  10: HRZ 5.1373 / 5.1427 Hz, consistent 5.1457 / 5.1568 Hz
  20: HRZ 5.1026 / 5.1034 Hz, consistent 5.1047 / 5.1069 Hz
  40: HRZ 5.0947 / 5.0948 Hz, consistent 5.0952 / 5.0957 Hz
"""

import itertools
import math
import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from simcli.geometry.tetmesh import box_tets
from simcli.solvers.fem import tet10

E, nu, rho = 1e8, 0.3, 1000.0
mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
res = float(sys.argv[1])
m = box_tets([0, -0.05, 0.4], [1, 0.05, 0.5], res)
x, T = tet10.quadratic_nodes(m.x, m.tets)
G, vol = tet10.quadrature_gradients(x, T)
n = x.shape[0]
ne = len(T)
# stiffness (linear elasticity), exact with the 4-point rule
w = 0.25 * vol[:, None] * np.ones(4)
I3 = np.eye(3)
gg = np.einsum("eqai,eqbi->eqab", G, G)
Ke = (
    np.einsum("eq,eqab,ij->eaibj", w, gg, mu * I3)
    + mu * np.einsum("eq,eqbi,eqaj->eaibj", w, G, G)
    + lam * np.einsum("eq,eqai,eqbj->eaibj", w, G, G)
).reshape(ne, 30, 30)
dof = (3 * T[:, :, None] + np.arange(3)).reshape(ne, 30)
K = sp.csr_matrix(
    (Ke.ravel(), (np.repeat(dof, 30, axis=1).ravel(), np.tile(dof, (1, 30)).ravel())), shape=(3 * n, 3 * n)
)
# consistent mass: N_a = L^T Q_a L (homogeneous quadratics), int L_i L_j L_k L_l dV = V 3! alpha! / 7!
Q = np.zeros((10, 4, 4))
for a in range(4):
    Q[a, a, a] += 2.0
    Q[a, a, :] -= 0.5
    Q[a, :, a] -= 0.5
for k, (i, j) in enumerate(tet10.EDGES):
    Q[4 + k, i, j] += 2.0
    Q[4 + k, j, i] += 2.0
Iq = np.zeros((4, 4, 4, 4))
for idx in itertools.product(range(4), repeat=4):
    cnt = np.bincount(idx, minlength=4)
    Iq[idx] = 6.0 * np.prod([math.factorial(c) for c in cnt]) / math.factorial(7)
Mref = np.einsum("aij,bkl,ijkl->ab", Q, Q, Iq)  # per unit volume
assert abs(Mref.sum() - 1) < 1e-12
Me = rho * vol[:, None, None] * Mref
Mdof = np.einsum("eab,ij->eaibj", Me, I3).reshape(ne, 30, 30)
Mc = sp.csr_matrix(
    (Mdof.ravel(), (np.repeat(dof, 30, axis=1).ravel(), np.tile(dof, (1, 30)).ravel())), shape=(3 * n, 3 * n)
)
Mh = sp.diags(np.repeat(tet10.lumped_mass(T, vol, rho * np.ones(ne), n), 3)).tocsr()
free = np.ones(3 * n, bool)
free[np.repeat(x[:, 0] < 1e-9, 3)] = False
Kf = K[free][:, free].tocsc()
for name, M in (("HRZ", Mh), ("consistent", Mc)):
    Mf = M[free][:, free].tocsc()
    ev = sla.eigsh(Kf, k=4, M=Mf, sigma=0, which="LM", return_eigenvectors=False)
    f = np.sqrt(np.sort(ev)) / (2 * np.pi)
    print(res, name, "lowest frequencies [Hz]", np.round(f, 4))
