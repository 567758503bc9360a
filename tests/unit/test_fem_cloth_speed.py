"""FEM.Cloth's cost-saving paths give what the plain ones do: the Newton matrix summed through the cached
sparsity map equals scipy's COO sum (entries of fixed dofs dropped, edge unknowns past 3n, the cache reused
for new values and refreshed for a new pattern), and the line search's energy-only evaluation equals the
energy of the full one, bit for bit."""

from __future__ import annotations

import textwrap
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("ipctk")
sp = pytest.importorskip("scipy.sparse")

from simcli.solvers.fem.cloth.solver import ClothSolver  # noqa: E402


def _owner(n, fixed):
    free = np.nonzero(np.repeat(~fixed, 3))[0]
    dof_map = np.full(3 * n, -1, dtype=np.int64)
    dof_map[free] = np.arange(len(free))
    return SimpleNamespace(n=n, free_dofs=free, _dof_map=dof_map, _pat=None)


def _reference(o, parts_r, parts_c, parts_v, N):
    R, C, V = (np.concatenate(p) for p in (parts_r, parts_c, parts_v))
    m = np.concatenate([o._dof_map, len(o.free_dofs) + np.arange(max(R.max() + 1 - 3 * o.n, 0))])
    r, c = m[R], m[C]
    keep = (r >= 0) & (c >= 0)
    return sp.coo_matrix((V[keep], (r[keep], c[keep])), shape=(N, N)).toarray()


def test_cached_pattern_sum_equals_the_coo_sum():
    rng = np.random.default_rng(3)
    n, n_aux = 7, 4
    fixed = np.zeros(n, bool)
    fixed[[1, 5]] = True
    o = _owner(n, fixed)
    N = len(o.free_dofs) + n_aux
    R = [rng.integers(0, 3 * n + n_aux, 300), rng.integers(0, 3 * n, 50)]
    C = [rng.integers(0, 3 * n + n_aux, 300), rng.integers(0, 3 * n, 50)]
    for k in range(3):  # the first builds the map, the second reuses it, the third has a new pattern
        if k == 2:
            R[1] = rng.integers(0, 3 * n, 50)
        V = [rng.standard_normal(300), rng.standard_normal(50)]
        pat_before = o._pat
        H = ClothSolver._fixed_pattern_sum(o, list(R), list(C), V, N)
        assert (o._pat is pat_before) == (k == 1)
        assert H.format == "csc" and H.has_sorted_indices
        np.testing.assert_allclose(H.toarray(), _reference(o, R, C, V, N), rtol=1e-13, atol=1e-13)


SCENE = """\
version: 1
sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.2}
domain: {lower: [-1, -1, 0], upper: [1, 1, 1]}
colliders:
  - {type: Sphere, center: [0, 0, 0.3], radius: 0.1, friction: 0.3}
solvers:
  fem: {contact_distance: 5.0e-3}
entities:
  - name: c
    material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 200, thickness: 1.0e-3, friction: 0.2}
    morph: {type: Rectangle, center: [0, 0, 0.42], size: [0.4, 0.4], resolution: 6}
"""


def test_energy_only_evaluation_equals_the_full_one(tmp_path):
    from simcli.scene.loader import load_scene

    p = tmp_path / "c.yaml"
    p.write_text(textwrap.dedent(SCENE))
    ld = load_scene(p)
    s = ClothSolver(ld.scene, [], scene_dir=ld.scene_dir)
    s.build()
    for _ in range(6):  # onto the sphere: obstacle barrier and friction active
        s.substep(0.01)
    s.dt = 0.01
    s.xn = s.x.copy()
    s.xhat = s.xn + 0.01 * s.v + 1e-4 * s.g
    s._fric = s._lagged_friction(s.xn)
    x = s.x + 1e-4 * np.random.default_rng(0).standard_normal(s.x.shape)
    e2, g2, H, nc = s._potential(x, 2)
    e1, g1, _, _ = s._potential(x, 1)
    e0, g0, _, nc0 = s._potential(x, 0)
    assert nc > 0 and nc0 == nc
    assert e0 == e1 == e2
    assert g0 is None and np.array_equal(g1, g2)
    assert H.shape[0] > 3 * s.n - 1  # the edge unknowns of the shape-operator bending are in the matrix
