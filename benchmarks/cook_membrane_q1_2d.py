"""Independent check of Cook's membrane (docs/FEM.md, Validation): 2D plane-strain bilinear quadrilaterals
(Q1, 2 x 2 Gauss points) in numpy/scipy, none of simcli's code: the deal.II code gallery's setup (Pelteret and
McBride 2016, doi:10.5281/zenodo.1228964: mu = 422.5 kPa, nu = 0.3, 1 N on the 16 mm edge of a 1 mm slab)
with its decoupled neo-Hookean psi = mu/2 (J^-2/3 I_C - 3) + kappa/4 (J^2 - 1 - 2 ln J) or Bonet and Wood's
(argument bw), F33 = 1, Newton over 10 load steps (tangent by central differences of P in F).
Prints the vertical displacement at (48, 52) mm, the reference's point, and at the corner (48, 60) mm.
Compare with the reference's Q1 column (8: 13.61, 16: 14.13, 32: 14.28, 64: 14.32 mm).

Usage: python benchmarks/cook_membrane_q1_2d.py N [decoupled|bw]   (N = elements per edge; 64: about a
minute). Measured 2026-11-26: decoupled 13.863 / 14.485 / 14.667 / 14.719 mm at 8 / 16 / 32 / 64; bw 14.445
at 32.
"""

import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

n = int(sys.argv[1])
model = sys.argv[2] if len(sys.argv) > 2 else "decoupled"
mu = 422.5e3
nu = 0.3
lam = 2 * mu * nu / (1 - 2 * nu)
kappa = lam + 2 * mu / 3

# nodes
xi = np.linspace(0, 1, n + 1)
S, T = np.meshgrid(xi, xi, indexing="ij")  # S along x, T along the height
X = 48.0 * S
yb, yt = 44.0 * S, 44.0 + 16.0 * S
Y = yb + T * (yt - yb)
P = np.stack([X.ravel(), Y.ravel()], axis=1) * 1e-3
nid = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
E = np.stack([nid[:-1, :-1], nid[1:, :-1], nid[1:, 1:], nid[:-1, 1:]], axis=-1).reshape(-1, 4)  # ccw
g = 1 / np.sqrt(3)
gp = [(-g, -g), (g, -g), (g, g), (-g, g)]
ref = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
dNs = []
for a, b in gp:
    dN = 0.25 * np.stack([ref[:, 0] * (1 + ref[:, 1] * b), ref[:, 1] * (1 + ref[:, 0] * a)], axis=1)  # (4, 2)
    dNs.append(dN)
dNs = np.array(dNs)  # (4q, 4a, 2)
Xe = P[E]  # (ne, 4, 2)
Jac = np.einsum("eai,qaj->eqij", Xe, dNs)  # dX/dxi
detJ = np.linalg.det(Jac)
assert (detJ > 0).all()
G = np.einsum("qaj,eqji->eqai", dNs, np.linalg.inv(Jac))  # dN/dX (ne, q, a, 2)
W = detJ  # weights 1


def stress(F2):
    """PK1 (2x2 block) of the 3D model with F33 = 1."""
    F = np.zeros(F2.shape[:-2] + (3, 3))
    F[..., :2, :2] = F2
    F[..., 2, 2] = 1.0
    J = np.linalg.det(F)
    Finv_T = np.swapaxes(np.linalg.inv(F), -1, -2)
    I1 = (F * F).sum(axis=(-1, -2))
    if model == "decoupled":
        Pk = (
            mu * J[..., None, None] ** (-2 / 3) * (F - (I1 / 3)[..., None, None] * Finv_T)
            + (kappa / 2 * (J * J - 1))[..., None, None] * Finv_T
        )
    else:  # Bonet-Wood
        Pk = mu * (F - Finv_T) + (lam * np.log(J))[..., None, None] * Finv_T
    return Pk[..., :2, :2]


fixed = np.nonzero(P[:, 0] < 1e-9)[0]
ndof = 2 * P.shape[0]
free = np.ones(ndof, bool)
free[2 * fixed] = False
free[2 * fixed + 1] = False
# load: right edge nodes, 62500 Pa along y per unit thickness (1 N over 16 mm x 1 mm)
right = nid[-1, :]
fext = np.zeros(ndof)
for k in range(n):
    a, b = right[k], right[k + 1]
    L = np.linalg.norm(P[b] - P[a])
    fext[2 * a + 1] += 0.5 * L * 62500.0
    fext[2 * b + 1] += 0.5 * L * 62500.0
u = np.zeros(ndof)
rows = np.repeat(np.repeat(2 * E[:, :, None] + np.arange(2)[None, None], 1, 0).reshape(len(E), 8), 8, axis=1)
cols = np.tile((2 * E[:, :, None] + np.arange(2)[None, None]).reshape(len(E), 8), (1, 8))


def internal(u):
    U = u.reshape(-1, 2)[E]  # (ne, 4, 2)
    F2 = np.eye(2) + np.einsum("eai,eqaj->eqij", U, G)
    Pk = stress(F2)
    fe = np.einsum("eq,eqij,eqaj->eai", W, Pk, G)
    f = np.zeros(ndof)
    np.add.at(f, (2 * E[:, :, None] + np.arange(2)).ravel(), fe.ravel())
    # tangent by central differences of P in F (4 components)
    h = 1e-7
    C = np.zeros(F2.shape[:2] + (2, 2, 2, 2))
    for k in range(2):
        for l in range(2):
            d = np.zeros((2, 2))
            d[k, l] = h
            C[..., k, l] = (stress(F2 + d) - stress(F2 - d)) / (2 * h)  # dP_ij / dF_kl
    Ke = np.einsum("eq,eqaj,eqijkl,eqbl->eaibk", W, G, C, G).reshape(len(E), 8, 8)
    K = sp.csr_matrix((Ke.ravel(), (rows.ravel(), cols.ravel())), shape=(ndof, ndof))
    return f, K


for step in range(1, 11):
    lf = step / 10
    for it in range(30):
        f, K = internal(u)
        r = (f - lf * fext)[free]
        if it == 0:
            r0 = np.linalg.norm(r) + 1e-30
        if np.linalg.norm(r) < 1e-10 * max(r0, np.linalg.norm(lf * fext)):
            break
        du = sla.spsolve(K[free][:, free].tocsc(), -r)
        u[free] += du
tip = np.nonzero(np.linalg.norm(P - [0.048, 0.052], axis=1) < 1e-9)[0]
corner = np.nonzero(np.linalg.norm(P - [0.048, 0.060], axis=1) < 1e-9)[0]
print(
    n,
    model,
    "uy(48,52) = %.4f mm" % (u[2 * tip + 1][0] * 1e3),
    "uy(48,60) = %.4f mm" % (u[2 * corner + 1][0] * 1e3),
)
