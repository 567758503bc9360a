"""FEM.Cloth's optional CHOLMOD factorisation (solvers.fem.linear_solver, cvxopt): the same Newton
directions as SuperLU to round-off, a refusal of an indefinite matrix that the solver's fallback catches,
the same sheet after a contact-rich drop, and validate's refusal of `cholmod` where cvxopt is missing."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from click.testing import CliRunner

from simcli.cli import cli
from simcli.solvers.fem.cloth.checks import cholmod_available

needs_cholmod = pytest.mark.skipif(not cholmod_available(), reason="cvxopt / threadpoolctl not installed")


def _spd(n=300, seed=0):
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    # a grid Laplacian (sparse, ill-conditioned like a membrane) plus a small random SPD coupling and a mass
    k = int(np.sqrt(n))
    lap1 = sp.diags([-np.ones(k - 1), 2 * np.ones(k), -np.ones(k - 1)], [-1, 0, 1])
    lap = sp.kronsum(lap1, lap1)
    B = sp.random(k * k, k * k, density=2.0 / (k * k), random_state=rng)
    return (lap + B @ B.T + 1e-3 * sp.identity(k * k)).tocsc(), rng.standard_normal(k * k)


@needs_cholmod
def test_cholmod_solves_as_superlu():
    import scipy.sparse.linalg as spl

    from simcli.solvers.fem.cloth.solver import CholmodFactor

    H, b = _spd()
    ref = spl.splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    x = CholmodFactor(H, CholmodFactor.blas_limit(1)).solve(b)
    assert np.abs(H @ x - b).max() < 1e-9 * np.abs(b).max() * 1e3
    assert x == pytest.approx(ref.solve(b), rel=1e-9, abs=1e-12)
    assert b.shape == x.shape  # and b is left as it was: solve works on a copy
    H2, b2 = _spd(seed=1)
    assert CholmodFactor(H2).solve(b2) == pytest.approx(spl.spsolve(H2, b2), rel=1e-9, abs=1e-12)


@needs_cholmod
def test_an_indefinite_matrix_is_refused():
    import scipy.sparse as sp

    from simcli.solvers.fem.cloth.solver import CholmodFactor

    H = sp.diags([1.0, -1.0, 2.0]).tocsc()
    with pytest.raises(ArithmeticError):
        CholmodFactor(H)


SCENE = """\
version: 1
sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.12}
domain: {lower: [-1, -1, 0], upper: [1, 1, 1]}
colliders:
  - {type: Sphere, center: [0, 0, 0.3], radius: 0.1, friction: 0.3}
solvers:
  fem: {contact_distance: 2.0e-3, linear_solver: %s}
entities:
  - name: c
    material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 200, thickness: 1.0e-3}
    morph: {type: Rectangle, center: [0, 0, 0.41], size: [0.4, 0.4], resolution: 10}
"""


@needs_cholmod
def test_the_sheet_lands_the_same_with_either_factorisation(tmp_path):
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections
    from simcli.solvers.fem.cloth.solver import ClothSolver

    out = {}
    for which in ("superlu", "cholmod"):
        p = tmp_path / f"{which}.yaml"
        p.write_text(SCENE % which)
        s = ClothSolver(load_scene(p).scene, [], scene_dir=None)
        s.build()
        for _ in range(12):
            s.substep(0.01)
        assert edge_triangle_intersections(s.x, s.tris) == []
        info = s.info()
        assert info["factorization"].startswith("CHOLMOD" if which == "cholmod" else "SuperLU")
        assert info["factorizations"] > 0 and info["contacts"] > 0
        out[which] = s.x.copy()
    # the same sheet to well within Newton's tolerance (the directions differ by round-off only)
    assert np.abs(out["cholmod"] - out["superlu"]).max() < 1e-6


def test_validate_refuses_cholmod_without_cvxopt(tmp_path, monkeypatch):
    import simcli.solvers.fem.cloth.checks as checks

    monkeypatch.setattr(checks, "cholmod_available", lambda: False)
    p = tmp_path / "s.yaml"
    p.write_text(textwrap.dedent(SCENE % "cholmod"))
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 65, r.output
    assert f"{p}:7:" in r.output and "solvers.fem.linear_solver" in r.output, r.output
    assert "pip install 'simcli[cholmod]'" in r.output
    p.write_text(textwrap.dedent(SCENE % "auto"))  # auto falls back to SuperLU: valid
    assert CliRunner().invoke(cli, ["validate", str(p)]).exit_code == 0
