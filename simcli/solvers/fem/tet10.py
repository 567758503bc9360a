"""Quadratic (10-node) tetrahedra for the FEM solver (``solvers.fem.element: tet10``).

The element is the linear mesh with one node added at the midpoint of each unique edge (straight-sided,
VTK's ``tetra10`` node order: corners 0-3, then the edges (0,1), (1,2), (0,2), (0,3), (1,3), (2,3)).
Quadratic shape functions in the barycentric coordinates L: corners N_a = L_a (2 L_a - 1), edge (i, j)
N = 4 L_i L_j. Each element is integrated with the 4-point degree-2 Gauss rule (Keast; points
(a, b, b, b) and its permutations, a = 0.58541020, b = 0.13819660, weight V / 4): F is linear in the
element, so the stiffness of linear elasticity (grad N . grad N, degree 2) is integrated exactly.

How it reuses the linear element's kernels: every **quadrature point** is a kernel "element" of its own
with ``nc = 10`` corners (the nodes of its tetrahedron), the shape-function gradients G_a at the point
(physical frame, per point), the weight w_q V as its volume and the identity as its ``B``. Then
F_q = sum_a x_a G_a^T, the energy sum_q w_q V psi(F_q), the forces -w_q V P(F_q) G_a and the Hessian
product w_q V dP(F_q)[dF_q] G_a are what the tet4 kernels already compute (``vol P B^T`` with B = I is
w_q V P; the scatter here multiplies by G_a per node), so backward Euler, implicit midpoint, the explicit
integrator, Rayleigh damping, contact (per node) and the preconditioners run unchanged, with per-point
singular-value-frame Hessian data. The linear element keeps its own kernels and is bit for bit as before.

Mass: lumped by HRZ (Hinton, Rock and Zienkiewicz 1976): the consistent mass's diagonal scaled to the
element's mass: corners rho V / 36, edge nodes 4 rho V / 27 (the consistent diagonal is rho V (6, 32) / 420).
Row sums of the consistent tet10 mass give the corners negative mass (-rho V / 20), so they are not used.
A diagonal mass keeps the implicit solver's mass term, predictor and contact penalty per node as they are.

Surface tractions: the consistent loads of a quadratic triangle under a uniform traction t on area A are
zero at its corners and t A / 3 at its three edge nodes.
"""

import numpy as np

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti

EDGES = ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))  # VTK tetra10 order of the edge nodes 4..9
_A, _B = 0.5854101966249685, 0.1381966011250105
# barycentric coordinates (L0, L1, L2, L3) of the 4 Gauss points; weights 1/4 each (of the volume)
QUAD_L = np.array([[_A, _B, _B, _B], [_B, _A, _B, _B], [_B, _B, _A, _B], [_B, _B, _B, _A]])
QUAD_W = np.full(4, 0.25)
NQ = 4
# explicit stable substep: the corner tetrahedra's smallest height times this. The edge nodes and the HRZ
# masses raise the highest eigenfrequency of M^-1 K: on Kuhn-split boxes (3^3 and 5^3 cells, linear
# elasticity, nu = 0.3) w_max(tet4) / w_max(tet10) = 0.398 and 0.396; 0.35 keeps tet4's margin and a bit
H_FACTOR = 0.35
NC = 10
# HRZ lumped mass per node, as a fraction of the element's mass
MASS_CORNER = 1.0 / 36.0
MASS_EDGE = 4.0 / 27.0


def quadratic_nodes(x: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tet10 mesh of a linear mesh: (nodes, (m, 10) connectivity). The n corner vertices keep their
    indices; the midpoint of each unique edge is appended (in the order of the sorted edge keys)."""
    x = np.asarray(x, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    n = x.shape[0]
    e = np.sort(tets[:, np.array(EDGES)], axis=2)  # (m, 6, 2)
    keys = e[..., 0] * n + e[..., 1]
    uniq, inv = np.unique(keys.reshape(-1), return_inverse=True)
    xm = 0.5 * (x[uniq // n] + x[uniq % n])
    t10 = np.concatenate([tets, n + inv.reshape(-1, 6)], axis=1)
    return np.concatenate([x, xm]), t10


def edge_node_lookup(t10: np.ndarray, n_corner: int):
    """(sorted edge keys i * n + j with i < j, their midpoint node) of a tet10 mesh (local indices)."""
    c = t10[:, :4]
    e = np.sort(c[:, np.array(EDGES)], axis=2)
    keys = (e[..., 0] * n_corner + e[..., 1]).reshape(-1)
    nodes = t10[:, 4:].reshape(-1)
    k, first = np.unique(keys, return_index=True)
    return k, nodes[first]


def face_edge_nodes(faces: np.ndarray, lookup, n_corner: int) -> np.ndarray:
    """The three edge nodes of triangles ``faces`` (corner indices, local): (nf, 3)."""
    keys, nodes = lookup
    out = np.empty_like(faces)
    for k, (a, b) in enumerate(((0, 1), (1, 2), (0, 2))):
        lo = np.minimum(faces[:, a], faces[:, b])
        hi = np.maximum(faces[:, a], faces[:, b])
        q = lo * n_corner + hi
        idx = np.searchsorted(keys, q)
        if np.any(idx >= len(keys)) or np.any(keys[np.minimum(idx, len(keys) - 1)] != q):
            raise ValueError("tet10: a boundary face edge has no midpoint node")
        out[:, k] = nodes[idx]
    return out


def shape_gradients_ref(L: np.ndarray) -> np.ndarray:
    """dN_a / dL_k at barycentric point L: (10, 4)."""
    D = np.zeros((10, 4))
    for a in range(4):
        D[a, a] = 4.0 * L[a] - 1.0
    for k, (i, j) in enumerate(EDGES):
        D[4 + k, i] = 4.0 * L[j]
        D[4 + k, j] = 4.0 * L[i]
    return D


def shape_values(L: np.ndarray) -> np.ndarray:
    N = np.empty(10)
    for a in range(4):
        N[a] = L[a] * (2.0 * L[a] - 1.0)
    for k, (i, j) in enumerate(EDGES):
        N[4 + k] = 4.0 * L[i] * L[j]
    return N


def quadrature_gradients(x: np.ndarray, t10: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per element and Gauss point the physical shape-function gradients (m, 4, 10, 3) and the volumes
    (m,) of the straight-sided elements (the Jacobian is constant: the corner tetrahedron's)."""
    c = t10[:, :4]
    X0 = x[c[:, 0]]
    Dm = np.stack([x[c[:, 1]] - X0, x[c[:, 2]] - X0, x[c[:, 3]] - X0], axis=2)
    B = np.linalg.inv(Dm)  # rows: gradients of L1, L2, L3
    gradL = np.concatenate([-B.sum(axis=1, keepdims=True), B], axis=1)  # (m, 4, 3)
    vol = np.linalg.det(Dm) / 6.0
    D = np.stack([shape_gradients_ref(L) for L in QUAD_L])  # (4, 10, 4)
    G = np.einsum("qak,mkj->mqaj", D, gradL)
    return G, vol


def lumped_mass(t10: np.ndarray, vol: np.ndarray, rho: np.ndarray, n: int) -> np.ndarray:
    """HRZ lumped nodal masses."""
    mass = np.zeros(n)
    me = rho * vol
    for a in range(4):
        np.add.at(mass, t10[:, a], MASS_CORNER * me)
    for a in range(4, 10):
        np.add.at(mass, t10[:, a], MASS_EDGE * me)
    return mass


def prepare(s) -> None:
    """Kernel data of the quadrature-point "elements" of solver ``s`` (host, numpy): s.mk points with
    s.nc = 10 corners; B = I, volume w_q V, material per point, the gradients, the vertex adjacency over the
    (point, node) slots, and the rest diagonal blocks for the preconditioner."""
    T = s.tets10
    m = T.shape[0]
    G, vol = quadrature_gradients(s.x0, T)
    s.G10 = G.reshape(m * NQ, NC, 3)
    s.mk, s.nc = m * NQ, NC
    s.Bk = np.broadcast_to(np.eye(3), (m * NQ, 3, 3)).copy()
    s.volk = (vol[:, None] * QUAD_W[None, :]).reshape(-1)
    s.midk = np.repeat(s.mid, NQ)
    s.tk = np.repeat(T, NQ, axis=0)  # (mk, 10): the nodes of each point's element
    flat = s.tk.reshape(-1)
    s.adj = np.argsort(flat, kind="stable").astype(np.int32)
    s.adj_start = np.concatenate([[0], np.cumsum(np.bincount(flat, minlength=s.n))]).astype(np.int32)


def rest_diagonal_blocks(s) -> np.ndarray:
    """Per (point, node) slot the 3x3 block w V (mu |g_a|^2 I + (mu + lam) g_a g_a^T) of the rest
    small-strain stiffness: summed over the slots of a node, the exact diagonal block."""
    G = s.G10  # (mk, 10, 3)
    mu = np.array([s.materials[k].mu for k in s.midk])
    lam = np.array([s.materials[k].lam for k in s.midk])
    g2 = np.einsum("eai,eai->ea", G, G)
    blocks = mu[:, None, None, None] * g2[:, :, None, None] * np.eye(3) + (mu + lam)[
        :, None, None, None
    ] * np.einsum("eai,eaj->eaij", G, G)
    return (s.volk[:, None, None, None] * blocks).reshape(-1, 3, 3)


def make_funcs(s):
    """Taichi funcs of the quadrature-point elements: deformation(e, xf), deformation_plus(e, xf, yf) (F of
    xf + yf), scatter(e, H) (H = w V P: per node H G_a into s.fe) and corner_grad(e, a)."""
    f = s.f
    mk = s.mk
    s.t10_f = ti.Vector.field(NC, ti.i32, shape=mk)
    s.G10_f = ti.Matrix.field(NC, 3, f, shape=mk)
    s.t10_f.from_numpy(s.tk.astype(np.int32))
    s.G10_f.from_numpy(s.G10.astype(s.npf))
    t10, G10, fe = s.t10_f, s.G10_f, s.fe

    @ti.func
    def deformation(e, xf: ti.template()):
        t = t10[e]
        x0 = xf[t[0]]
        F = ti.Matrix.zero(float, 3, 3)
        for a in ti.static(range(1, NC)):
            d = xf[t[a]] - x0  # sum_a G_a = 0: differences keep f32 round-off at the element's size
            for i in ti.static(range(3)):
                for j in ti.static(range(3)):
                    F[i, j] += d[i] * G10[e][a, j]
        return F

    @ti.func
    def deformation_plus(e, xf: ti.template(), yf: ti.template()):
        t = t10[e]
        x0 = xf[t[0]] + yf[t[0]]
        F = ti.Matrix.zero(float, 3, 3)
        for a in ti.static(range(1, NC)):
            d = xf[t[a]] + yf[t[a]] - x0
            for i in ti.static(range(3)):
                for j in ti.static(range(3)):
                    F[i, j] += d[i] * G10[e][a, j]
        return F

    @ti.func
    def corner_grad(e, a):
        g = ti.Vector.zero(float, 3)
        for j in ti.static(range(3)):
            g[j] = G10[e][a, j]
        return g

    @ti.func
    def scatter(e, H):
        for a in ti.static(range(NC)):
            g = ti.Vector([G10[e][a, 0], G10[e][a, 1], G10[e][a, 2]])
            fe[NC * e + a] = H @ g

    return deformation, deformation_plus, scatter, corner_grad


__all__ = [
    "EDGES",
    "QUAD_L",
    "QUAD_W",
    "edge_node_lookup",
    "face_edge_nodes",
    "lumped_mass",
    "make_funcs",
    "prepare",
    "quadratic_nodes",
    "quadrature_gradients",
    "rest_diagonal_blocks",
    "shape_values",
]
