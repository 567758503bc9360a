"""Free rigid bodies from closed surface meshes (issue 20: "6-DOF from primitives or closed meshes"):
exact polyhedral mass properties, the scene checks (exit 65 with the location), and one small 3D MPM run
where a Mesh cube behaves as the Box body of the same shape, a Mesh cube rests on a Box body and a Mesh
ball on the domain floor."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
MESHES = ROOT / "configs" / "meshes"


def _surface(name: str, scale=1.0, rotate=(0.0, 0.0, 0.0), translate=(0.0, 0.0, 0.0)):
    from simcli.geometry.mesh import load_mesh_morph
    from simcli.scene.morphs import MeshShape

    m = MeshShape(
        type="Mesh", file=str(MESHES / name), scale=scale, rotate=list(rotate), translate=list(translate)
    )
    mesh = load_mesh_morph(m, None)
    return mesh.vertices, mesh.triangles


def test_mesh_mass_properties_are_the_polyhedron_s():
    from simcli.motion import quat_to_matrix
    from simcli.rigid.body import mesh_mass_properties

    # a box: the cube scaled per axis and moved
    s = np.array([0.1, 0.2, 0.3])
    V, T = _surface("cube.obj", scale=list(s), translate=(1.0, -2.0, 0.5))
    m, c, In = mesh_mass_properties(V, T, 500.0)
    assert m == pytest.approx(500.0 * s.prod(), rel=1e-12)
    assert c == pytest.approx([1.0, -2.0, 0.5], abs=1e-12)
    box = m / 12.0 * np.array([s[1] ** 2 + s[2] ** 2, s[0] ** 2 + s[2] ** 2, s[0] ** 2 + s[1] ** 2])
    assert In == pytest.approx(np.diag(box), abs=1e-12)
    # the same box turned: the inertia turns with it (R I R^T), the mass and centre stay
    V, T = _surface("cube.obj", scale=list(s), rotate=(30.0, 0.0, 0.0))
    m2, c2, In2 = mesh_mass_properties(V, T, 500.0)
    a = math.radians(30.0)
    R = quat_to_matrix(np.array([math.cos(a / 2), math.sin(a / 2), 0.0, 0.0]))
    assert m2 == pytest.approx(m, rel=1e-12) and c2 == pytest.approx([0, 0, 0], abs=1e-12)
    assert In2 == pytest.approx(R @ np.diag(box) @ R.T, abs=1e-12)
    # a torus about z (ring radius R0, tube r0, from the file's extent): V = 2 pi^2 R0 r0^2; the
    # polyhedron is inscribed, so it is a little smaller (1152 vertices: within 2 %)
    V, T = _surface("torus.obj", translate=(0.3, 0.2, 0.1))
    m, c, In = mesh_mass_properties(V, T, 1.0)
    r0 = 0.5 * (V[:, 2].max() - V[:, 2].min())
    R0 = 0.5 * (V[:, 0].max() - V[:, 0].min()) - r0
    assert m == pytest.approx(2 * math.pi**2 * R0 * r0**2, rel=0.02) and m < 2 * math.pi**2 * R0 * r0**2
    assert c == pytest.approx([0.3, 0.2, 0.1], abs=1e-9)
    Izz = m * (R0**2 + 0.75 * r0**2)  # a thin-walled check of the axis: Izz > Ixx = Iyy
    assert In[2, 2] == pytest.approx(Izz, rel=0.03) and In[0, 0] == pytest.approx(In[1, 1], rel=1e-6)


def _validate(tmp_path, text: str):
    p = tmp_path / "scene.yaml"
    p.write_text(textwrap.dedent(text))
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)], capture_output=True, text=True, cwd=ROOT
    )
    return r.returncode, r.stdout + r.stderr


SCENE3 = """\
version: 1
sim: {{dim: 3, dt: 2.0e-3, substeps: auto, steps: 100}}
domain: {{lower: [0, 0, 0], upper: [0.24, 0.12, 0.16]}}
solvers:
  mpm: {{grid_density: 40}}
rigid_bodies:
  - name: plain
    morph: {{type: Box, center: [0.06, 0.06, 0.075], size: [0.05, 0.05, 0.05]}}
    rho: 500
  - name: meshcube
    morph: {{type: Mesh, file: {cube}, scale: 0.03, translate: [0.06, 0.06, 0.117]}}
    rho: 500
  - name: meshball
    morph: {{type: Mesh, file: {ball}, scale: 0.025, translate: [0.19, 0.06, 0.035]}}
    rho: 300
{entities}
"""
ENT = """\
entities:
  - name: block
    material: {type: MPM.Elastic, E: 2.0e5, nu: 0.3, rho: 1000}
    morph: {type: Box, lower: [0.0, 0.0, 0.0], upper: [0.12, 0.12, 0.05]}
"""


def test_mesh_bodies_are_checked_with_the_location(tmp_path):
    cube, ball = MESHES / "cube.obj", MESHES / "icosphere.obj"
    rc, out = _validate(tmp_path, SCENE3.format(cube=cube, ball=ball, entities=ENT))
    assert rc == 0, out
    rc, out = _validate(tmp_path, SCENE3.format(cube=tmp_path / "nope.obj", ball=ball, entities=ENT))
    assert rc == 65 and "rigid_bodies.1.morph.file" in out and "not found" in out, out
    rc, out = _validate(tmp_path, SCENE3.format(cube=cube, ball=ball, entities=ENT).replace("0.117", "0.09"))
    assert rc == 65 and "overlaps rigid body 'meshcube'" in out, out  # the mesh cube sunk into the box
    pbf = ENT.replace("MPM.Elastic, E: 2.0e5, nu: 0.3", "PBD.Liquid").replace(
        "upper: [0.12, 0.12, 0.05]", "upper: [0.12, 0.12, 0.03]"
    )
    rc, out = _validate(tmp_path, SCENE3.format(cube=cube, ball=ball, entities=pbf))
    assert rc == 0, out  # PBF counts a Mesh body's solid in its density (its density map)
    sph = pbf.replace("PBD.Liquid", "SPH.Liquid")  # SPH meets Mesh bodies (boundary particles from the grid)
    rc, out = _validate(tmp_path, SCENE3.format(cube=cube, ball=ball, entities=sph))
    assert rc == 0, out
    flat2d = """\
    version: 1
    sim: {dim: 2, dt: 1.0e-3, steps: 10}
    domain: {lower: [0, 0], upper: [0.2, 0.2]}
    rigid_bodies:
      - {name: m, morph: {type: Mesh, file: %s, scale: 0.03, translate: [0.1, 0.1, 0.0]}, rho: 500}
    entities:
      - name: block
        material: {type: MPM.Elastic, E: 1.0e4, nu: 0.3, rho: 1000}
        morph: {type: Box, lower: [0.0, 0.0], upper: [0.2, 0.04]}
    """
    rc, out = _validate(tmp_path, flat2d % cube)  # a 2D Mesh body is a polygon: a 3D surface is refused
    assert rc == 65 and "rigid_bodies.0.morph.file" in out and "needs dim 3" in out, out
    flat = tmp_path / "open.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\n")  # one face missing
    rc, out = _validate(tmp_path, SCENE3.format(cube=flat, ball=ball, entities=ENT))
    assert rc == 65 and "rigid_bodies.1.morph.file" in out, out


def test_a_mesh_cube_floats_as_the_box_body_and_rests_on_bodies_and_walls(tmp_path):
    """A Mesh cube on a Box body on an MPM elastic block, and a Mesh ball on the bare floor: at 0.2 s the
    Box body carries both cubes' weight, the Mesh cube sits on the Box's top face and the ball on the
    floor, each within a millimetre, and the materials' force on the Box is the two cubes' weight."""
    cube, ball = MESHES / "cube.obj", MESHES / "icosphere.obj"
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE3.format(cube=cube, ball=ball, entities=ENT))
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "rigid body 'meshcube'" in r.stdout + r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        g = f["rigid_bodies"]
        plain, mc, mb = (np.asarray(g[n]["position"][-1]) for n in ("plain", "meshcube", "meshball"))
        m_plain, m_cube = g["plain"].attrs["mass"], g["meshcube"].attrs["mass"]
        assert g["meshcube"].attrs["shape"] == "Mesh" and g["meshcube"]["surface_points"].shape == (8, 3)
        f_plain = np.asarray(g["plain"]["force"][-5:]).mean(axis=0)
        v_end = max(float(np.linalg.norm(g[n]["velocity"][-1])) for n in ("plain", "meshcube", "meshball"))
    assert m_cube == pytest.approx(500.0 * 0.03**3, rel=1e-9)
    assert v_end < 0.02
    assert mc[2] == pytest.approx(plain[2] + 0.025 + 0.015, abs=1e-3)  # on the Box body's top face
    assert mc[:2] == pytest.approx(plain[:2], abs=1e-3)
    assert mb[2] == pytest.approx(0.025, abs=1e-3)  # the icosphere's lowest vertex on the floor
    weight = (m_plain + m_cube) * 9.81
    assert f_plain[2] == pytest.approx(weight, rel=0.05)
    assert (out / "vtk" / "meshcube.pvd").exists() and (out / "vtk" / "meshball.pvd").exists()
