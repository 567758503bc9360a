"""`type: Mesh` colliders and `restitution` through `simcli validate`: bad meshes and unsupported uses are
refused with exit 65, the scene's file:line:col and what to change (no Taichi: validate is fast)."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCENE = """\
version: 1
sim: {{dim: {dim}, steps: 2}}
domain: {{lower: {lower}, upper: {upper}}}
colliders:
  - type: Mesh
    file: {file}
    translate: [0.5, 0.5, 0.5]
    scale: 0.2{extra}
solvers: {{fem: {{integrator: {integrator}}}}}
entities:
  - name: b
    material: {material}
    morph: {{type: Box, lower: {elo}, upper: {ehi}}}
"""

CUBE_OPEN = "\n".join(
    ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 0 0 1", "f 1 3 2", "f 1 2 4", "f 1 4 3"]  # a tetrahedron less a face
)
NONMANIFOLD = "\n".join(  # two tetrahedra sharing an edge: it is used by four triangles
    ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 0 0 1", "v 0 -1 0", "v 0 0 -1"]
    + ["f 1 3 2", "f 1 2 4", "f 1 4 3", "f 2 3 4", "f 1 2 5", "f 1 6 2", "f 1 5 6", "f 2 6 5"]
)
COPLANAR = "\n".join(["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0", "f 1 3 2", "f 1 2 4", "f 1 4 3", "f 2 3 4"])


def _validate(tmp_path, file="cube.obj", mesh_text=None, dim=3, extra="", integrator="explicit", **kw):
    if mesh_text is not None:
        (tmp_path / file).write_text(mesh_text + "\n")
    elif file == "cube.obj":
        shutil.copy(ROOT / "configs" / "meshes" / "cube.obj", tmp_path / file)
    lo, hi = ([0, 0, 0], [1, 1, 1]) if dim == 3 else ([0, 0], [1, 1])
    fields = dict(
        dim=dim,
        lower=lo,
        upper=hi,
        file=file,
        extra=extra,
        integrator=integrator,
        material="{type: PBD.Particle, rho: 1000}",
        elo=[0.1] * dim,
        ehi=[0.2] * dim,
    )
    fields.update(kw)
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE.format(**fields))
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(scene)], capture_output=True, text=True, timeout=120
    )
    return r, scene


def _located(r, scene, line: int, key: str):
    assert r.returncode == 65, r.stderr
    assert "Traceback" not in r.stderr
    m = re.search(rf"{re.escape(str(scene))}:{line}:\d+: {re.escape(key)}: (.*)", r.stderr)
    assert m, r.stderr
    return m.group(1)


def test_a_good_mesh_collider_validates(tmp_path):
    r, _ = _validate(tmp_path, extra="\n    restitution: 0.5")
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize(
    "file, text, words",
    [
        ("missing.obj", None, ["not found", "relative to the scene file"]),
        ("open.obj", CUBE_OPEN, ["not a closed surface", "boundary edge", "repair"]),
        ("nm.obj", NONMANIFOLD, ["not a closed surface", "non-manifold", "repair"]),
        ("flat.obj", COPLANAR, ["encloses no volume", "closed surface around a volume"]),
    ],
)
def test_bad_mesh_files_are_refused_at_the_file_key(tmp_path, file, text, words):
    r, scene = _validate(tmp_path, file=file, mesh_text=text)
    msg = _located(r, scene, 6, "colliders.0.file")
    for w in words:
        assert w in msg


def test_mesh_collider_in_2d_is_refused(tmp_path):
    r, scene = _validate(tmp_path, dim=2)
    assert "need dim 3" in _located(r, scene, 5, "colliders.0.type")


def test_entity_entirely_inside_a_mesh_collider_is_refused(tmp_path):
    r, scene = _validate(tmp_path, elo=[0.45] * 3, ehi=[0.55] * 3)
    assert "entirely inside colliders.0 (Mesh)" in _located(r, scene, 13, "entities.0.morph")


def test_restitution_with_implicit_fem_is_refused(tmp_path):
    r, scene = _validate(
        tmp_path,
        extra="\n    restitution: 0.5",
        integrator="implicit",
        material="{type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000}",
    )
    msg = _located(r, scene, 9, "colliders.0.restitution")
    assert "explicit" in msg
