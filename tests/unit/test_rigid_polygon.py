"""2D Mesh rigid bodies (issue 20, simcli/rigid/polygon.py): a closed polygon read from a file, its exact
area, centroid and polar moment, its signed-distance grid, and the scene checks (exit 65 with the key's
location). The Archimedes drafts are verify cases (rigid_archimedes_sph_2d_mesh_rho500,
rigid_archimedes_mpm_2d_mesh_rho500)."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
SQUARE = ROOT / "configs" / "meshes" / "square.obj"


def test_polygon_mass_properties_are_exact():
    from simcli.rigid.polygon import polygon_mass_properties

    m, c, J = polygon_mass_properties(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]), 3.0)
    assert m == pytest.approx(6.0) and c == pytest.approx([1.0, 0.5]) and J == pytest.approx(6.0 * 5 / 12)
    # a right triangle (legs a, b): area ab/2, centroid (a/3, b/3), polar moment about it m (a^2 + b^2) / 18
    a, b = 0.3, 0.2
    m, c, J = polygon_mass_properties(np.array([[0.0, 0.0], [a, 0.0], [0.0, b]]), 1000.0)
    assert m == pytest.approx(1000 * a * b / 2) and c == pytest.approx([a / 3, b / 3])
    assert J == pytest.approx(m * (a * a + b * b) / 18)
    # a regular 64-gon of circumradius r: close to a disk's m r^2 / 2
    th = np.linspace(0, 2 * math.pi, 64, endpoint=False)
    m, c, J = polygon_mass_properties(0.1 * np.stack([np.cos(th), np.sin(th)], 1), 500.0)
    assert J / (0.5 * m * 0.01) == pytest.approx(1.0, abs=2e-3) and np.abs(c).max() < 1e-12


def test_a_square_file_gives_the_box_bodys_numbers_and_a_signed_distance(tmp_path):
    from simcli.rigid.body import RigidBodyModel
    from simcli.scene.models import Scene

    def scene(morph):
        return Scene.model_validate(
            {
                "sim": {"dim": 2},
                "domain": {"lower": [0, 0], "upper": [0.4, 0.3]},
                "solvers": {"mpm": {"grid_density": 100}},
                "entities": [
                    {
                        "name": "w",
                        "material": {"type": "MPM.Elastic"},
                        "morph": {"type": "Box", "lower": [0, 0], "upper": [0.4, 0.05]},
                    }
                ],
                "rigid_bodies": [{"name": "b", "morph": morph, "rho": 500}],
            }
        )

    box = scene({"type": "Box", "center": [0.2, 0.165], "size": [0.08, 0.08]})
    sq = scene(
        {"type": "Mesh", "file": str(SQUARE), "scale": 0.08, "rotate": [0.0], "translate": [0.2, 0.165]}
    )
    a, b = RigidBodyModel(box.rigid_bodies[0], 2), RigidBodyModel(sq.rigid_bodies[0], 2, sq)
    assert b.mass == pytest.approx(a.mass) and b.pivot == pytest.approx(a.pivot)
    assert b.inertia[2, 2] == pytest.approx(a.inertia[2, 2])
    sdf = b.spec.mesh
    assert sdf.h == pytest.approx(0.005)  # half the MPM cell
    x = np.array([[0.2, 0.165], [0.2, 0.125 + 0.01], [0.2, 0.125 - 0.01], [0.26, 0.165], [0.25, 0.215]])
    want = [-0.04, -0.01, 0.01, 0.02, math.hypot(0.01, 0.01)]
    assert sdf.sample(x) == pytest.approx(want, abs=1e-9)  # exact on the nodes and along the faces
    assert sdf.normal(x[3:4])[0] == pytest.approx([1.0, 0.0], abs=1e-6)
    # turned 30 degrees about its centre: the same mass, its corners turned
    tq = scene(
        {"type": "Mesh", "file": str(SQUARE), "scale": 0.08, "rotate": [0, 0, 30], "translate": [0, 0]}
    )
    V = RigidBodyModel(tq.rigid_bodies[0], 2, tq).spec.mesh.vertices
    ang = np.degrees(np.arctan2(V[:, 1], V[:, 0])) % 90
    assert ang == pytest.approx(np.full(4, 75.0))


def test_an_outline_of_l_lines_reads_as_its_polygon(tmp_path):
    from simcli.rigid.polygon import read_polygon, signed_area

    p = tmp_path / "l.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 1 2 0\nv 0 2 0\nl 1 2\nl 3 2\nl 3 4\nl 4 1\n")
    assert abs(signed_area(read_polygon(p)[:, :2])) == pytest.approx(2.0)


def _validate(tmp_path, text):
    f = tmp_path / "s.yaml"
    f.write_text(textwrap.dedent(text))
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(f)], capture_output=True, text=True, cwd=ROOT
    )
    return r.returncode, r.stdout + r.stderr


SCENE2 = """\
version: 1
sim: {dim: 2, dt: 1.0e-3, steps: 10}
domain: {lower: [0, 0], upper: [0.4, 0.3]}
entities:
  - name: w
    material: %s
    morph: {type: Box, lower: [0.0, 0.0], upper: [0.4, 0.05]}
rigid_bodies:
  - name: m
    morph: {type: Mesh, file: %s, scale: 0.08, translate: [0.2, 0.165]}
    rho: 500
"""
MPM = "{type: MPM.Elastic, E: 1.0e4, nu: 0.3, rho: 1000}"


def test_2d_mesh_bodies_are_checked_with_the_location(tmp_path):
    rc, out = _validate(tmp_path, SCENE2 % (MPM, SQUARE))
    assert rc == 0, out
    bow = tmp_path / "bow.obj"  # a bow tie: its outline crosses itself
    bow.write_text("v 0 0 0\nv 1 1 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 4\n")
    rc, out = _validate(tmp_path, SCENE2 % (MPM, bow))
    assert rc == 65 and "s.yaml:10:" in out and "crosses itself" in out and "Traceback" not in out, out
    rc, out = _validate(tmp_path, SCENE2 % ("{type: PBD.Elastic, rho: 1000}", SQUARE))
    assert rc == 65 and "s.yaml:10:" in out and "MPM and SPH entities so far" in out, out
    rc, out = _validate(
        tmp_path, (SCENE2 % (MPM, SQUARE)).replace("translate: [0.2, 0.165]", "translate: [0.2, 0.04]")
    )
    assert rc == 65 and "overlaps entity 'w'" in out, out


def test_a_polygon_file_with_a_bad_vertex_index_is_refused_with_the_location(tmp_path):
    """An f or l line naming a vertex that is not there (past the v lines, 0, or not a number) is a scene
    error at morph.file, not a traceback (review, 2026-11-27: 'f 1 2 3 9' on 4 vertices raised IndexError)."""
    for name, face, what in [
        ("past.obj", "f 1 2 3 9", "out of range"),
        ("zero.obj", "f 0 1 2 3", "out of range"),
        ("neg.obj", "f -1 -2 -9", "out of range"),
        ("word.obj", "f a b c", "not a vertex index"),
        ("line.obj", "l 1 2 3 7 1", "out of range"),
    ]:
        p = tmp_path / name
        p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n" + face + "\n")
        rc, out = _validate(tmp_path, SCENE2 % (MPM, p))
        assert rc == 65 and "s.yaml:10:" in out and what in out and "Traceback" not in out, (name, out)


# outlines that meet themselves without a proper crossing: each passed validate before 2026-11-27 (review:
# "a self-touching polygon passes"), and each gives a wrong area, centroid and moment or a sliver of no width
SELF_TOUCHING = [
    # a vertex (v 4) on a non-neighbouring edge (v 1 -> v 2): two triangles joined at a point
    (
        "touch.obj",
        "v 0 0 0\nv 2 0 0\nv 2 2 0\nv 1 0 0\nv 0 2 0\nf 1 2 3 4 5\n",
        "v line 1 (0, 0) to v line 2 (2, 0)",
    ),
    # the edge v 5 -> v 6 runs along the edge v 1 -> v 2 (collinear overlap: no sign change to see)
    (
        "overlap.obj",
        "v 0 0 0\nv 3 0 0\nv 3 1 0\nv 2 1 0\nv 2 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4 5 6 7 8\n",
        "v line 1 (0, 0) to v line 2 (3, 0)",
    ),
    # a figure eight: two squares through one point given twice (v 3 and v 7)
    (
        "eight.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 2 1 0\nv 2 2 0\nv 1 2 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4 5 6 7 8\n",
        "v line 7 (1, 1)",
    ),
    # a spike of no width: v 4 and back along the same line
    (
        "spike.obj",
        "v 0 0 0\nv 2 0 0\nv 2 1 0\nv 3 1 0\nv 1.5 1 0\nv 0 1 0\nf 1 2 3 4 5 6\n",
        "at v line 4 (3, 1)",
    ),
    # one vertex twice in a row (an edge of no length)
    (
        "dup.obj",
        "v 0 0 0\nv 1 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4 5\n",
        "v line 2 (1, 0) and v line 3 (1, 0)",
    ),
]


@pytest.mark.parametrize("name,text,where", SELF_TOUCHING, ids=[c[0] for c in SELF_TOUCHING])
def test_a_self_touching_polygon_is_refused_at_validate_naming_the_edges(tmp_path, name, text, where):
    p = tmp_path / name
    p.write_text(text)
    rc, out = _validate(tmp_path, SCENE2 % (MPM, p))
    assert rc == 65 and "s.yaml:10:" in out and "rigid_bodies.0.morph.file" in out, out
    assert "itself" in out and where in out and "Traceback" not in out, out


def test_self_contact_finds_the_crossing_edges_and_passes_simple_outlines():
    from simcli.rigid.polygon import self_contact, simple

    bow = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    assert self_contact(bow) == ("cross", 0, 2)
    # simple outlines, either orientation, scaled far down and far up: no false contact
    th = np.linspace(0, 2 * math.pi, 41, endpoint=False)
    star = (1 + 0.6 * np.cos(7 * th))[:, None] * np.stack([np.cos(th), np.sin(th)], 1)
    ell = np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 2], [0, 2]], float)
    sub = np.array(
        [[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1], [0, 1]], float
    )  # extra vertices on straight sides
    for P in (star, star[::-1], ell, ell[::-1], 1e-6 * star, 1e4 * ell + 7.0, sub, sub[::-1]):
        assert simple(P)
    # a comb whose teeth are 1e-6 of its size apart still passes (not touching), at 0 it is refused
    for gap, ok in ((1e-6, True), (0.0, False)):
        comb = np.array([[0, 0], [2, 0], [2, 1], [1 + gap, 1], [1 + gap, 0.5], [1, 0.5], [1, 1], [0, 1]])
        assert simple(comb) is ok


def test_run_refuses_a_self_touching_polygon_as_validate_does(tmp_path):
    """validate and run agree: run exits 65 with validate's message at the same location, before any
    output is written."""
    name, text, where = SELF_TOUCHING[0]
    p = tmp_path / name
    p.write_text(text)
    rc, vout = _validate(tmp_path, SCENE2 % (MPM, p))
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(tmp_path / "s.yaml"), "-o", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    rout = r.stdout + r.stderr
    assert rc == 65 and r.returncode == 65, (vout, rout)
    line = next(ln for ln in vout.splitlines() if where in ln)
    assert line in rout and "Traceback" not in rout, (vout, rout)
    assert not (out / "sim.h5").exists()
