"""Quadratic (10-node) tetrahedra (solvers.fem.element: tet10, simcli/solvers/fem/tet10.py):

* mesh conversion: one node per unique edge at its midpoint, corners unchanged (on a Kuhn-split box the
  tet10 nodes are exactly the grid of half the spacing);
* element patch test (numpy): a linear displacement field is reproduced exactly at every Gauss point
  (F = I + A), a uniform stress leaves no force on interior nodes, the 4-point rule integrates the volume
  and the stiffness's integrands exactly, HRZ masses are positive and sum to the element mass;
* solver patch test (slow: Taichi, f64, one quasi-static implicit step of the uniaxial-tension cube with
  the linear model): strain 1e-3 along the load and -3e-4 across at every node, corners and edge nodes.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simcli.geometry.tetmesh import box_tets, signed_volumes
from simcli.solvers.fem import tet10

ROOT = Path(__file__).resolve().parents[2]


def test_quadratic_nodes_are_edge_midpoints():
    mesh = box_tets([0, 0, 0], [1, 1, 1], 2.0)  # 2 x 2 x 2 cells, 48 tets
    x, t10 = tet10.quadratic_nodes(mesh.x, mesh.tets)
    n = mesh.x.shape[0]
    edges = {tuple(sorted((int(t[i]), int(t[j])))) for t in mesh.tets for i, j in tet10.EDGES}
    assert x.shape[0] == n + len(edges)
    assert np.array_equal(x[:n], mesh.x) and np.array_equal(t10[:, :4], mesh.tets)
    for k, (i, j) in enumerate(tet10.EDGES):  # every edge node sits at its edge's midpoint
        assert np.allclose(x[t10[:, 4 + k]], 0.5 * (x[t10[:, i]] + x[t10[:, j]]), atol=1e-15)
    # one node per unique edge: the same edge in two tets maps to the same node, different edges differ
    pairs = {}
    for t in t10:
        for k, (i, j) in enumerate(tet10.EDGES):
            key = tuple(sorted((int(t[i]), int(t[j]))))
            assert pairs.setdefault(key, int(t[4 + k])) == int(t[4 + k])
    assert len(set(pairs.values())) == len(edges)
    # Kuhn subdivision: axis edges, face and body diagonals: the edge midpoints fill the half-spacing grid
    g = np.round(x * 4).astype(int)
    assert len({tuple(p) for p in g}) == 5**3 == x.shape[0]


def _patch_mesh():
    mesh = box_tets([0, 0, 0], [1, 0.7, 0.5], 3.0)
    rng = np.random.default_rng(0)
    x = mesh.x.copy()
    interior = np.all((x > 1e-9) & (x < np.array([1, 0.7, 0.5]) - 1e-9), axis=1)
    x[interior] += rng.uniform(-0.04, 0.04, (interior.sum(), 3))  # distorted elements
    assert (signed_volumes(x, mesh.tets) > 0).all()
    return tet10.quadratic_nodes(x, mesh.tets)


def test_element_patch_linear_field_and_uniform_stress():
    x, t10 = _patch_mesh()
    G, vol = tet10.quadrature_gradients(x, t10)
    assert (vol > 0).all()
    A = np.array([[1e-3, 2e-4, -3e-4], [5e-4, -2e-3, 1e-4], [0.0, 7e-4, 4e-4]])
    u = x @ A.T + np.array([0.1, -0.2, 0.3])
    F = np.einsum("mai,mqaj->mqij", (x + u)[t10], G)
    assert np.abs(F - (np.eye(3) + A)).max() < 1e-12  # the linear field reproduced exactly
    # partition of unity in the gradients, and the rule integrates grad N_a (degree 1) exactly:
    assert np.abs(G.sum(axis=2)).max() < 1e-10
    # uniform stress P: nodal forces -sum_q w V P G_a vanish on interior nodes (they cancel between elements)
    P = np.array([[3.0, 1.0, 0.5], [1.0, -2.0, 0.2], [0.5, 0.2, 1.5]])
    f = np.zeros_like(x)
    w = 0.25 * vol[:, None] * np.ones(4)
    np.add.at(f, t10.reshape(-1), -np.einsum("mq,ij,mqaj->mai", w, P, G).reshape(-1, 3))
    lo, hi = x.min(axis=0), x.max(axis=0)
    inner = np.all((x > lo + 1e-9) & (x < hi - 1e-9), axis=1)
    assert inner.sum() > 10 and np.abs(f[inner]).max() < 1e-12
    # the boundary forces are the traction P n: their total moment balances and their sum vanishes
    assert np.abs(f.sum(axis=0)).max() < 1e-12


def test_quadrature_exact_for_stiffness_and_hrz_mass():
    x = np.array([[0.0, 0, 0], [1.0, 0.1, 0], [0.2, 0.9, 0.1], [0.1, 0.2, 1.1]])
    xq, t10 = tet10.quadratic_nodes(x, np.array([[0, 1, 2, 3]]))
    G, vol = tet10.quadrature_gradients(xq, t10)
    # grad N_a . grad N_b is quadratic: the 4-point rule against a 3rd-degree-exact 11-point reference is
    # replaced here by the exact integral from barycentric monomials (int L^a = a! 3! V / (a + 3)!)
    K4 = np.einsum("q,qai,qbi->ab", 0.25 * vol[0] * np.ones(4), G[0], G[0])
    # exact: dN/dL is linear in L; int L_i L_j dV = V (1 + delta_ij) / 20, int L_i = V / 4
    c = xq[t10[0, :4]]
    Dm = np.stack([c[1] - c[0], c[2] - c[0], c[3] - c[0]], axis=1)
    B = np.linalg.inv(Dm)
    gradL = np.concatenate([-B.sum(axis=0, keepdims=True), B])  # (4, 3)
    # dN_a/dL_k = sum_l C[a, k, l] L_l (linear, no constant term since 4 L - 1 = 4 L - sum L)
    C = np.zeros((10, 4, 4))
    for a in range(4):
        C[a, a, :] = -1.0
        C[a, a, a] += 4.0
    for k, (i, j) in enumerate(tet10.EDGES):
        C[4 + k, i, j] = 4.0
        C[4 + k, j, i] = 4.0
    M2 = vol[0] * (np.ones((4, 4)) + np.eye(4)) / 20.0  # int L_l L_m
    Kex = np.einsum("akl,bmn,ki,mi,ln->ab", C, C, gradL, gradL, M2)
    assert np.abs(K4 - Kex).max() < 1e-10 * np.abs(Kex).max()
    m = tet10.lumped_mass(t10, vol, np.array([1000.0]), xq.shape[0])
    assert (m > 0).all() and abs(m.sum() - 1000.0 * vol[0]) < 1e-12
    assert np.allclose(m[:4] / m[4:].min(), (1 / 36) / (4 / 27))


SCRIPT = r"""
import json, sys
from simcli.backend import init_taichi
init_taichi("cpu", "f64")
from simcli.scene.loader import load_scene
from simcli.solvers.fem.solver import FEMSolver

sets = ["solvers.fem.element=tet10", "solvers.fem.resolution=1"]
sc = load_scene(sys.argv[1] + "/configs/validation/fem_patch.yaml", sets).scene
s = FEMSolver(sc, []); s.build(); s.substep(sc.sim.dt)
x0, x = s.x0, s.positions(); u = x - x0
i = x0[:, 0] > 0.25; j = x0[:, 1] > 0.25
ex = u[i, 0] / x0[i, 0]; ey = u[j, 1] / x0[j, 1]
print("RESULT " + json.dumps(dict(n=int(s.n), m=int(s.m), ex=[ex.min(), ex.max()], ey=[ey.min(), ey.max()],
                                  mass=float(s.mass.sum())), default=float))
"""


@pytest.mark.slow  # compiles the tet10 implicit kernels: 19 s wall, warm kernel cache, loaded machine
def test_solver_patch_uniaxial_tension_exact(tmp_path):
    script = tmp_path / "run.py"
    script.write_text(SCRIPT)
    r = subprocess.run([sys.executable, str(script), str(ROOT)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-4000:]
    out = json.loads(next(ln for ln in r.stdout.splitlines() if ln.startswith("RESULT "))[7:])
    assert out["m"] == 6 and out["n"] == 27  # one cube cell: 6 tets, the 3 x 3 x 3 half-spacing grid
    assert abs(out["mass"] - 1000.0) < 1e-9
    for v in out["ex"]:
        assert abs(v - 1e-3) < 1e-12
    for v in out["ey"]:
        assert abs(v + 3e-4) < 1e-12


SCENE_REFUSED = """version: 1
sim: {dim: 3, dt: 0.01, steps: 2}
domain: {lower: [-1, -1, -1], upper: [1, 1, 1]}
solvers:
  fem: {integrator: implicit, element: tet10}
entities:
  - name: muscle
    material: {type: FEM.Muscle, E: 1.0e5, nu: 0.3}
    morph: {type: Box, lower: [0, 0, 0], upper: [0.2, 0.2, 0.2]}
  - name: sand
    material: {type: MPM.Sand}
    morph: {type: Box, lower: [0, 0, 0.5], upper: [0.2, 0.2, 0.7]}
"""


def test_validate_refuses_what_tet10_does_not_support(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE_REFUSED)
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(scene)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert r.returncode == 65, r.stdout + r.stderr
    out = r.stdout + r.stderr
    assert f"{scene}:8:" in out and "FEM.Muscle is not supported with solvers.fem.element: tet10" in out
    assert f"{scene}:11:" in out and "MPM.Sand entities are not coupled to quadratic FEM solids" in out
    assert "Traceback" not in out
