"""FEM.Muscle, host side (no Taichi build): group assignment by the elements' rest centroids, fibre
directions, the actuation signals shared with MPM.Muscle, the explicit stability bound, and bad input
rejected as an invalid scene (exit 65)."""

import math
import subprocess
import sys

import numpy as np
import pytest
import yaml

SCENE = {
    "version": 1,
    "sim": {"dim": 3, "dt": 1e-3, "steps": 1, "gravity": [0, 0, 0]},
    "domain": {"lower": [-1, -1, -1], "upper": [1, 1, 1]},
    "solvers": {"fem": {"integrator": "explicit", "resolution": 20}},
    "entities": [
        {
            "name": "m",
            "material": {
                "type": "FEM.Muscle",
                "E": 1e5,
                "nu": 0.3,
                "stiffness": 2e5,
                "n_groups": 2,
                "fiber_direction": [0, 0, 2],
                "groups": [
                    {
                        "region": {"type": "Box", "lower": [-1, -1, -1], "upper": [0, 1, 1]},
                        "fiber_direction": [3, 4, 0],
                        "actuation": {"type": "sine", "amplitude": 0.5, "frequency": 2},
                    },
                    {"actuation": {"type": "table", "times": [0, 1], "values": [0, 0.25]}},
                ],
            },
            "morph": {"type": "Box", "lower": [-0.2, -0.05, -0.05], "upper": [0.2, 0.05, 0.05]},
        }
    ],
}


def _solver(tmp_path, scene):
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.solver import FEMSolver

    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(scene))
    sc = load_scene(p, []).scene
    return FEMSolver(sc, [])


def test_groups_fibres_and_signals(tmp_path):
    s = _solver(tmp_path, SCENE)
    assert s.has_muscle and len(s.signals) == 2
    cen = s.x0[s.tets].mean(axis=1)
    left = cen[:, 0] <= 0
    assert (s.el_group[left] == 0).all() and (s.el_group[~left] == 1).all()
    assert np.allclose(s.el_fiber[left], [0.6, 0.8, 0.0]) and np.allclose(s.el_fiber[~left], [0, 0, 1])
    assert np.allclose(s.el_k, 2e5)
    assert math.isclose(s.signals[0](0.125), 0.5) and math.isclose(s.signals[1](0.5), 0.125)
    # the P-wave speed bound grows with the largest activation: 1 + k max|a| / (lambda + 2 mu)
    m = s.materials[0]
    c0 = math.sqrt((m.lam + 2 * m.mu) / m.rho)
    assert math.isclose(s.c_p, c0 * math.sqrt(1 + 2e5 * 0.5 / (m.lam + 2 * m.mu)), rel_tol=1e-12)


def test_elastic_body_has_no_muscle(tmp_path):
    sc = yaml.safe_load(yaml.safe_dump(SCENE))
    sc["entities"][0]["material"] = {"type": "FEM.Elastic", "E": 1e5, "nu": 0.3}
    assert not _solver(tmp_path, sc).has_muscle


@pytest.mark.parametrize(
    "patch, message",
    [
        ({"n_groups": 3}, "groups has 2 entries but n_groups is 3"),
        ({"fiber_direction": [0, 0, 0]}, "fiber_direction needs 3 components, not all zero"),
        ({"fiber_direction": [1, 0]}, "fiber_direction needs 3 components, not all zero"),
    ],
)
def test_bad_muscle_is_an_invalid_scene(tmp_path, patch, message):
    sc = yaml.safe_load(yaml.safe_dump(SCENE))
    sc["entities"][0]["material"].update(patch)
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(sc))
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 65 and message in r.stderr, r.stderr


# --------------------------------------------------------------- FEM scene checks (simcli validate)

CHECK_SCENE = """version: 1
sim: {dim: 3, dt: 1.0e-3, steps: 1}
domain: {lower: [-1, -1, -1], upper: [1, 1, 1]}
solvers:
  fem: {resolution: RES}
entities:
  - name: b
    material: {type: FEM.Elastic}
    morph: MORPH
"""


def _validate(
    tmp_path, res=20, morph="{type: Box, lower: [-0.5, -0.5, -0.5], upper: [0.5, 0.5, 0.5]}", dim=3
):
    text = CHECK_SCENE.replace("RES", str(res)).replace("MORPH", morph)
    if dim == 2:
        text = (
            text.replace("dim: 3", "dim: 2")
            .replace("[-1, -1, -1]", "[-1, -1]")
            .replace("[1, 1, 1]", "[1, 1]")
            .replace("[-0.5, -0.5, -0.5]", "[-0.5, -0.5]")
            .replace("[0.5, 0.5, 0.5]", "[0.5, 0.5]")
        )
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_fem_scene_checks(tmp_path):
    assert _validate(tmp_path).returncode == 0
    r = _validate(tmp_path, dim=2)
    assert r.returncode == 65 and "FEM.Elastic entities need a 3D scene (sim.dim: 3)" in r.stderr, r.stderr
    r = _validate(tmp_path, res=3000)
    assert r.returncode == 65 and "solvers.fem.resolution: scene too large" in r.stderr, r.stderr
    assert "162,000,000,000 tetrahedra" in r.stderr, r.stderr  # 3000^3 cells x 6


def test_fem_sphere_without_tetgen_names_the_package(tmp_path):
    import importlib.util

    if importlib.util.find_spec("tetgen") is not None:
        pytest.skip("tetgen is installed here")
    r = _validate(tmp_path, morph="{type: Sphere, center: [0, 0, 0], radius: 0.2}")
    assert r.returncode == 65 and "pip install tetgen" in r.stderr, r.stderr
