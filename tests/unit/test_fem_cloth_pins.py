"""FEM.Cloth prescribed motion (issue 21): pinned vertices that move (material.fixed_velocity as PBD, or
fixed_motion per region) and moving colliders, both Dirichlet motion inside the implicit step, limited by
the continuous collision check. Small sheets, a few substeps (host numpy/scipy/ipctk only, no Taichi)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ipctk")
pytest.importorskip("scipy")

from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections  # noqa: E402
from tests.unit.test_fem_cloth import _solver  # noqa: E402

HEAD = """\
version: 1
sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.1, gravity: %(g)s}
domain: {lower: [-0.5, -0.5, -0.5], upper: [0.5, 0.5, 0.5]}
%(col)s
solvers:
  fem: {contact_distance: 2.0e-3}
entities:
  - name: c
    material:
      type: FEM.Cloth
      E: 1.0e5
      rho: 200
      thickness: 1.0e-3
%(mat)s
    morph: {type: Rectangle, center: [0, 0, 0], size: [0.3, 0.2], resolution: [6, 4]}
%(fixed)s
"""
EDGES = """\
    fixed:
      - {type: Box, lower: [-0.16, -0.2, -0.01], upper: [-0.14, 0.2, 0.01]}
      - {type: Box, lower: [0.14, -0.2, -0.01], upper: [0.16, 0.2, 0.01]}
"""

# a sphere falling 18 cm in 18 ms (10 m/s) from 10 cm above the sheet: its keyframed motion within a step is
# part of the Newton step
FAST_SPHERE = """\
colliders:
  - type: Sphere
    center: [0.0, 0.0, 0.1]
    radius: 0.04
    motion: {keyframes: {times: [0, 0.018], translate: [[0, 0, 0], [0, 0, -0.18]]}}
"""


def _scene(tmp_path, g="[0, 0, -9.81]", col="", mat="", fixed=EDGES):
    p = tmp_path / "cloth.yaml"
    p.write_text(textwrap.dedent(HEAD % dict(g=g, col=col, mat=mat, fixed=fixed)))
    return p


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_fixed_velocity_moves_the_pins_on_their_path(tmp_path):
    """As PBD's: the held vertices go x0 + fixed_velocity t exactly; the rest follows (no intersection)."""
    s = _solver(_scene(tmp_path, mat="      fixed_velocity: [0, 0, 0.5]"))
    X = s.X.copy()
    for k in range(1, 6):
        s.substep(0.01)
        t = 0.01 * k
        np.testing.assert_allclose(s.x[s.fixed], X[s.fixed] + [0, 0, 0.5 * t], atol=1e-12)
        assert np.isfinite(s.x).all() and edge_triangle_intersections(s.x, s.tris) == []
    assert s.stats["pin_lag_max"] == 0.0
    np.testing.assert_allclose(s.v[s.fixed], np.tile([0, 0, 0.5], (int(s.fixed.sum()), 1)), atol=1e-9)
    # the free vertices are pulled up with the pins (the sheet's middle lags behind: it sags)
    mid = ~s.fixed
    assert 0.0 < s.x[mid, 2].mean() < 0.5 * 0.05


def test_fixed_motion_turns_each_region_its_own_way(tmp_path):
    """Two edges twisted in opposite senses about the strip's axis: each pinned vertex is at R(+-w t) x0
    (pivot: its region's centre, on the axis), the sheet between them twists and nothing intersects."""
    mat = """\
      fixed_motion:
        - {angular_velocity: [6.0, 0, 0]}
        - {angular_velocity: [-6.0, 0, 0]}"""
    s = _solver(_scene(tmp_path, g="[0, 0, 0]", mat=mat))
    X = s.X.copy()
    left = s.fixed & (X[:, 0] < 0)
    right = s.fixed & (X[:, 0] > 0)
    for k in range(1, 11):
        s.substep(0.01)
        assert np.isfinite(s.x).all() and edge_triangle_intersections(s.x, s.tris) == []
    a = 6.0 * 0.1
    np.testing.assert_allclose(s.x[left], X[left] @ _rot_x(a).T, atol=1e-12)
    np.testing.assert_allclose(s.x[right], X[right] @ _rot_x(-a).T, atol=1e-12)
    # the middle section turned by about half of each end's angle in between (a twist, not a shear)
    mid = np.abs(X[:, 0] - 0.05) < 1e-9
    sec = s.x[mid][np.argsort(X[mid, 1])]
    ang = np.arctan2(sec[-1, 2] - sec[0, 2], sec[-1, 1] - sec[0, 1])
    assert -a < ang < 0.0  # between the right end's -a and the centre's 0


def test_a_fast_moving_sphere_never_gets_inside_the_sheet(tmp_path):
    """A sphere at 10 m/s (10 cm a substep, 50 contact distances) into a sheet pinned at its two edges,
    stopping 8 cm below them: its motion within the step is part of the Newton step, so the CCD stops it
    at the sheet, which is carried along; at every substep every vertex is outside the sphere at its pose."""
    s = _solver(_scene(tmp_path, g="[0, 0, 0]", col=FAST_SPHERE))
    for k in range(1, 4):
        s.substep(0.01)
        c = np.array([0, 0, 0.1 - min(10.0 * 0.01 * k, 0.18)])
        d = np.linalg.norm(s.x - c, axis=1) - 0.04
        assert np.isfinite(s.x).all() and d.min() > 0, (k, d.min())
        assert edge_triangle_intersections(s.x, s.tris) == []
    assert s.tau == pytest.approx(0.03, abs=1e-12)  # the sphere was never held back
    assert s.x[:, 2].min() < -0.05  # carried down under it, pinned edges at z = 0


def test_static_pins_leave_the_solve_unchanged(tmp_path):
    """A fixed_velocity of zero is plain pinning: no Dirichlet path is taken."""
    s = _solver(_scene(tmp_path, mat="      fixed_velocity: [0, 0, 0]"))
    assert not s.dirichlet and not s.moving_pins


@pytest.mark.parametrize(
    "mat, fixed, what",
    [
        ("      fixed_motion: [{angular_velocity: [1, 0, 0]}, {}, {}]", EDGES, "3 motions for 2 fixed"),
        ("      fixed_velocity: [0, 0, 1]", "", "no `fixed` region"),
        (
            "      fixed_velocity: [0, 0, 1]\n      fixed_motion: [{angular_velocity: [1, 0, 0]}]",
            EDGES,
            "not both",
        ),
    ],
)
def test_bad_pin_motion_is_refused_with_location(tmp_path, mat, fixed, what):
    from simcli.errors import SceneError
    from simcli.scene.loader import load_scene

    with pytest.raises(SceneError) as ei:
        load_scene(_scene(tmp_path, mat=mat, fixed=fixed))
    msg = str(ei.value)
    assert what in msg and "cloth.yaml:" in msg and "material.fixed_" in msg, msg


def test_bad_pin_motion_exits_65(tmp_path):
    """The command line's answer to the same (one case: the others take the same path)."""
    p = _scene(tmp_path, mat="      fixed_motion: [{angular_velocity: [1, 0, 0]}, {}, {}]")
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 65 and "3 motions for 2 fixed" in r.stderr and "cloth.yaml:" in r.stderr, r.stderr


def test_a_mesh_collider_next_to_the_scene_joins_the_contact(tmp_path):
    """A Mesh collider was refused (then a traceback) before FEM.Cloth met Mesh colliders; now its file,
    relative to the scene's folder, is read and its triangles join the cloth's ipctk collision mesh
    (test_fem_cloth_mesh_collider.py checks the contact itself)."""
    from simcli.scene.loader import load_scene

    col = "colliders:\n  - {type: Mesh, file: cube.obj, scale: 0.05, translate: [0, 0, -0.3]}"
    (tmp_path / "cube.obj").write_text(
        (Path(__file__).parents[2] / "configs" / "meshes" / "cube.obj").read_text()
    )
    load_scene(_scene(tmp_path, col=col))  # validates
    s = _solver(_scene(tmp_path, col=col))
    assert s.nm == 8 and s.cm.num_vertices == s.n + 8 and s.cm.num_faces == len(s.tris) + 12


def test_state_round_trip_keeps_the_colliders_time(tmp_path):
    """Checkpoints carry the moving colliders' own time (tau): a solver restored mid-run continues as the
    uninterrupted one (to round-off), whatever tau is."""
    p = _scene(tmp_path, g="[0, 0, 0]", col=FAST_SPHERE)
    a = _solver(p)
    for _ in range(2):
        a.substep(0.01)
    st = a.get_state()
    assert st["tau"][0] == pytest.approx(0.02)
    b = _solver(p)
    b.set_state(st)
    for _ in range(2):
        a.substep(0.01)
        b.substep(0.01)
    assert b.tau == a.tau
    np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-12)
    st["tau"] = np.array([0.015])  # a collider held back by a contact: it catches up from there
    b.set_state(st)
    assert b.tau == 0.015


def test_moving_collider_checks_read_the_scene_folder_and_report_bad_motion(tmp_path):
    """The start-inside check takes the colliders at their pose at t = 0 with the scene's own folder: a CSV
    motion next to the scene validates from anywhere, and a bad keyframe list is a located error (both were
    tracebacks: the check read the CSV relative to the working directory and raised on bad keyframes)."""
    from simcli.errors import SceneError
    from simcli.scene.loader import load_scene

    (tmp_path / "m.csv").write_text("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0,0,-0.1,1,0,0,0\n")
    col = "colliders:\n  - {type: Sphere, center: [0, 0, 0.2], radius: 0.05, motion: {file: m.csv}}"
    load_scene(_scene(tmp_path, col=col))  # no error, from the test's working directory
    col = (
        "colliders:\n  - {type: Sphere, center: [0, 0, 0.2], radius: 0.05,\n"
        "     motion: {keyframes: {times: [0, 1], translate: [[0, 0, 0]]}}}"
    )
    with pytest.raises(SceneError) as ei:
        load_scene(_scene(tmp_path, col=col))
    msg = str(ei.value)
    assert "translate needs one entry per time" in msg and "cloth.yaml:" in msg, msg
