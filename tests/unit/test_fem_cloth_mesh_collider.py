"""FEM.Cloth against `type: Mesh` colliders (issue 21): the collider's triangles are obstacle vertices and
faces of ipctk's collision mesh (barrier, friction and CCD on cloth-collider point-triangle and edge-edge
pairs), static or in prescribed motion. Every check of intersection is the independent segment-triangle test
(geometry.edge_triangle_intersections) on the cloth and the collider's triangles together. Small sheets, a
few substeps (host numpy/scipy/ipctk only, no Taichi)."""

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

MESHES = Path(__file__).resolve().parents[2] / "configs" / "meshes"

SCENE = """\
version: 1
sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.3}
domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 0.6]}
colliders:
  - name: body
    type: Mesh
    file: %(file)s
    scale: %(scale)s
    translate: %(translate)s
    friction: %(mu)s
%(motion)s
solvers:
  fem: {contact_distance: %(dhat)s}
entities:
  - name: c
    material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 200, thickness: 1.0e-3, friction: 0.2}
    morph: {type: Rectangle, center: %(center)s, size: %(size)s, resolution: %(res)s}
"""


def _scene(tmp_path, **kw):
    d = dict(
        file=str(MESHES / "cube.obj"),
        scale=0.2,
        translate="[0, 0, 0.2]",
        mu=0.3,
        motion="",
        dhat="2.0e-3",
        center="[0.01, 0.02, 0.31]",
        size="[0.16, 0.16]",
        res=6,
    )
    d.update(kw)
    p = tmp_path / "cloth.yaml"
    p.write_text(textwrap.dedent(SCENE % d))
    return p


def _crossings(s):
    """Segment-triangle crossings of the cloth and the Mesh colliders' triangles at their current pose."""
    X = np.concatenate([s.x, s.vobs])
    T = np.concatenate([s.tris, s.mobst.T + s.n])
    return edge_triangle_intersections(X, T)


BOX = """\
colliders:
  - {name: body, type: Box, lower: [-0.1, -0.1, 0.1], upper: [0.1, 0.1, 0.3], friction: 0.3}
"""


@pytest.mark.parametrize("kind", ["Mesh", "Box"])
def test_cloth_rests_on_a_static_box_and_its_weight_is_read_on_it(tmp_path, kind):
    """A 16 cm sheet dropped 1 cm onto the top of a 20 cm box, a triangulated Mesh (two triangles across its
    top) or the Box primitive (its 12 exact triangles in the same IPC contact): never a crossing, it comes
    to rest on the top within contact_distance, and the load on the collider is the sheet's weight (the
    barrier's reaction)."""
    p = _scene(tmp_path)
    if kind == "Box":
        txt = p.read_text()
        p.write_text(txt[: txt.index("colliders:")] + BOX + txt[txt.index("solvers:") :])
    s = _solver(p)
    assert (s.nm, len(s.mobst.T)) == (8, 12) and s.obst.specs == []
    loads = []
    for _ in range(30):
        s.substep(0.01)
        assert np.isfinite(s.x).all() and _crossings(s) == []
        loads.append(s.collider_loads()["body"])
    z = s.x[:, 2]
    assert z.min() > 0.3 and z.max() < 0.3 + 2e-3  # on the top, inside the barrier's reach
    assert np.abs(s.v).max() < 0.05  # at rest
    weight = 200 * 1e-3 * 0.16**2 * 9.81
    F = np.mean(loads[-5:], axis=0) / 0.01  # impulse per substep -> force [N]
    assert F[2] == pytest.approx(-weight, rel=0.02)
    assert np.abs(F[:2]).max() < 0.02 * weight
    # its moment about the box's centre (0, 0, 0.2): the weight acts at the sheet's centre of mass
    c = np.average(s.x, axis=0, weights=s.mass) - [0, 0, 0.2]
    M = np.mean(loads[-5:], axis=0)[3:] / 0.01
    np.testing.assert_allclose(M, np.cross(c, [0, 0, -weight]), atol=0.03 * weight * 0.02)


def test_a_sheet_draped_over_a_box_edge_is_never_cut_by_it(tmp_path):
    """A 0.4 m sheet dropped onto a 0.2 m `type: Box` collider drapes over its four top edges: the box's
    edges must not cut the sheet's triangles (a signed distance per cloth vertex let them: crossings from
    the 4th substep on); the box enters the IPC contact as its 12 triangles, checked here against the
    box's corners built independently."""
    p = _scene(tmp_path, size="[0.4, 0.4]", res=8)
    txt = p.read_text()
    p.write_text(txt[: txt.index("colliders:")] + BOX + txt[txt.index("solvers:") :])
    s = _solver(p)
    lo, hi = np.array([-0.1, -0.1, 0.1]), np.array([0.1, 0.1, 0.3])
    corners = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
    np.testing.assert_array_equal(np.sort(s.vobs, axis=0), np.sort(corners, axis=0))
    for _ in range(12):
        s.substep(0.01)
        assert np.isfinite(s.x).all() and _crossings(s) == []
    inside = np.all((s.x > lo) & (s.x < hi), axis=1)
    assert not inside.any()
    assert s.x[:, 2].min() < 0.3 - 0.03  # it did drape over the edges (the corners hang below the top)


def test_a_turning_box_moves_as_its_triangles(tmp_path):
    """A `type: Box` collider in prescribed motion is prescribed obstacle vertices (the Mesh path): its
    corners at each finished substep are its pose at that time (about its centre)."""
    p = _scene(tmp_path)
    txt = p.read_text()
    box = BOX.rstrip().rstrip("}") + ", motion: {angular_velocity: [0, 0, 6.283185307179586]}}\n"
    p.write_text(txt[: txt.index("colliders:")] + box + txt[txt.index("solvers:") :])
    s = _solver(p)
    assert s.mobst.moving and s.obst.specs == [] and s.dirichlet
    for _ in range(3):
        s.substep(0.01)
        assert _crossings(s) == []
        if s.tau == pytest.approx(s.time, abs=1e-12):
            np.testing.assert_allclose(s.vobs, s.mobst.positions(s.time), atol=1e-12)
    # corner (0.1, 0.1, 0.3) after turning by 2 pi tau about the vertical axis through (0, 0, 0.2)
    r = np.sqrt(2) * 0.1
    ang = np.pi / 4 + 2 * np.pi * s.tau
    assert np.min(np.linalg.norm(s.vobs - [r * np.cos(ang), r * np.sin(ang), 0.3], axis=1)) < 1e-9


def test_a_turning_mesh_plate_sweeps_a_falling_cloth_without_crossing_it(tmp_path):
    """A plate (the cube scaled to 30 x 0.6 x 4 cm) turning at 2 rev/s about the vertical axis catches a
    sheet falling on its 6 mm top edge: never a crossing nor a NaN, the plate reaches its prescribed angle at
    every substep's end (or lags only while a contact holds it), and the sheet is carried round the axis
    (angular momentum about z of the plate's sign)."""
    motion = "    motion: {angular_velocity: [0, 0, 12.566370614359172]}"
    p = _scene(
        tmp_path,
        scale="[0.3, 0.006, 0.04]",
        translate="[0, 0, 0.2]",
        motion=motion,
        center="[0, 0.02, 0.228]",
        size="[0.2, 0.2]",
        res=7,
    )
    s = _solver(p)
    assert s.dirichlet and s.mobst.moving
    torque_z = 0.0
    for k in range(12):
        s.substep(0.01)
        assert np.isfinite(s.x).all() and np.isfinite(s.v).all()
        assert _crossings(s) == []
        torque_z += s.collider_loads()["body"][5]
        if s.tau == pytest.approx(s.time, abs=1e-12):  # not held back: exactly at its pose
            np.testing.assert_allclose(s.vobs, s.mobst.positions(s.time), atol=1e-12)
    r = s.x - [0, 0, 0.2]
    Lz = float(np.sum(s.mass * (r[:, 0] * s.v[:, 1] - r[:, 1] * s.v[:, 0])))
    assert Lz > 0
    assert torque_z < 0  # the sheet resists the plate's turn: the reaction's moment about the pivot
    assert s.stats["collider_lag_max"] < 0.01  # never held back a whole substep


def test_a_keyframed_mesh_presses_a_cloth_onto_the_floor_without_crossing(tmp_path):
    """A box (keyframes: down 5.5 cm in 0.05 s, then still) comes down on a sheet lying on the floor: its
    bottom face stops 5 mm over the floor, the sheet (3.5 mm over it) squeezed between the two barriers
    (contact_distance 2 mm), never crossed; the box ends where its last keyframe puts it."""
    motion = "    motion: {keyframes: {times: [0, 0.05], translate: [[0, 0, 0], [0, 0, -0.055]]}}"
    p = _scene(
        tmp_path,
        scale="[0.1, 0.1, 0.04]",
        translate="[0, 0, 0.08]",
        motion=motion,
        center="[0, 0, 0.0035]",
        size="[0.2, 0.2]",
        res=6,
        mu=0.0,
    )
    s = _solver(p)
    for _ in range(8):
        s.substep(0.01)
        assert np.isfinite(s.x).all() and _crossings(s) == []
        assert s.x[:, 2].min() > 0
        assert s.vobs[:, 2].min() > s.x[:, 2].max() - 0.03  # the box's bottom never went below the sheet
    bottom = float(s.vobs[:, 2].min())
    np.testing.assert_allclose(s.vobs, s.mobst.positions(0.08), atol=1e-12)  # at its last keyframe
    assert bottom == pytest.approx(0.005, abs=1e-9)
    inner = np.all(np.abs(s.x[:, :2]) < 0.04, axis=1)
    assert s.x[inner, 2].max() < bottom  # the sheet stays under the box


def test_state_round_trip_keeps_the_moving_mesh_where_it_was(tmp_path):
    """Checkpoints carry the moving Mesh colliders' vertices (on the CCD's chord while a contact holds them
    back): a solver restored mid-run continues as the uninterrupted one (to round-off)."""
    motion = "    motion: {angular_velocity: [0, 0, 12.566370614359172]}"
    kw = dict(scale="[0.3, 0.006, 0.04]", motion=motion, center="[0, 0.02, 0.228]", size="[0.2, 0.2]", res=5)
    p = _scene(tmp_path, **kw)
    a = _solver(p)
    for _ in range(4):
        a.substep(0.01)
    st = a.get_state()
    assert "vobs" in st
    b = _solver(p)
    b.set_state(st)
    for _ in range(2):
        a.substep(0.01)
        b.substep(0.01)
    np.testing.assert_array_equal(a.vobs, b.vobs)
    # to round-off: ipctk builds its collision sets in parallel, so contact sums come in a run-dependent
    # order (two runs of main's fem_cloth_stack differ by 1.5e-8 m); a missing state would differ by mm
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)


def _validate(path):
    return subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(path)], capture_output=True, text=True, timeout=120
    )


def test_a_cloth_starting_through_a_mesh_collider_exits_65_with_the_location(tmp_path):
    p = _scene(tmp_path, center="[0.01, 0.02, 0.25]")  # the sheet cuts the box's side walls
    r = _validate(p)
    assert r.returncode == 65, r.stderr
    assert "colliders.0 (Mesh)" in r.stderr and "cloth.yaml:" in r.stderr and "near [" in r.stderr, r.stderr
    from simcli.errors import SceneError
    from simcli.scene.loader import load_scene

    for kw, what in (
        (
            dict(size="[0.1, 0.1]", center="[0.01, 0.02, 0.25]"),
            "start inside colliders.0 (Mesh)",
        ),  # in the box
        (dict(center="[0.01, 0.02, 0.301]"), "closer than solvers.fem.contact_distance"),  # 1 mm over its top
    ):
        with pytest.raises(SceneError) as ei:
            load_scene(_scene(tmp_path, **kw))
        assert what in str(ei.value) and "cloth.yaml:" in str(ei.value), str(ei.value)


@pytest.mark.parametrize(
    "what, motion, domain",
    [
        ("finite", "    motion: {angular_velocity: [.inf, 0, 0]}", None),  # was a math domain error
        ("lower", "", "domain: {lower: [-0.5, -0.5], upper: [0.5, 0.5, 0.6]}"),  # was an IndexError
    ],
)
def test_bad_scenes_with_a_mesh_collider_are_located_errors(tmp_path, what, motion, domain):
    from simcli.errors import SceneError
    from simcli.scene.loader import load_scene

    p = _scene(tmp_path, motion=motion)
    if domain:
        txt = p.read_text()
        p.write_text(txt.replace("domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 0.6]}", domain))
    with pytest.raises(SceneError) as ei:
        load_scene(p)
    assert what in str(ei.value) and "cloth.yaml:" in str(ei.value), str(ei.value)


def test_a_box_edge_through_a_cloth_triangle_at_the_start_is_a_located_error(tmp_path):
    """A thin Box pillar through the middle of a coarse sheet's triangle, every cloth vertex far from it (the
    per-vertex signed distance sees nothing): the triangle check of the Mesh path finds the box's edge."""
    from simcli.errors import SceneError
    from simcli.scene.loader import load_scene

    p = _scene(tmp_path, center="[0, 0, 0.2]", size="[0.4, 0.4]", res=1)
    txt = p.read_text()
    pillar = "colliders:\n  - {type: Box, lower: [0.09, -0.01, 0.1], upper: [0.11, 0.01, 0.3]}\n"
    p.write_text(txt[: txt.index("colliders:")] + pillar + txt[txt.index("solvers:") :])
    with pytest.raises(SceneError) as ei:
        load_scene(p)
    msg = str(ei.value)
    assert "intersects colliders.0 (Box) at the start" in msg and "cloth.yaml:" in msg, msg


def test_a_box_collider_with_two_components_is_a_located_error_not_a_traceback(tmp_path):
    """A Box's lower with 2 components in a 3D cloth scene: the collider checks' located message (the cloth's
    obstacle checks skip it; they raised a broadcasting ValueError)."""
    from simcli.errors import SceneError
    from simcli.scene.loader import load_scene

    p = _scene(tmp_path)
    txt = p.read_text()
    bad = "colliders:\n  - {type: Box, lower: [-0.1, -0.1], upper: [0.1, 0.1, 0.3]}\n"
    p.write_text(txt[: txt.index("colliders:")] + bad + txt[txt.index("solvers:") :])
    with pytest.raises(SceneError) as ei:
        load_scene(p)
    msg = str(ei.value)
    assert "colliders.0.lower" in msg and "expected 3 components" in msg and "cloth.yaml:5:" in msg, msg
