"""FEM.Cloth against free rigid bodies (issues 20, 21): a body's triangles join the cloth's IPC collision
mesh, its 6 dofs unknowns of the cloth's Newton system (held dofs moved at their prescribed rate), and the
contact's reaction goes back to the body through the load the world reads (simcli.rigid.world). Small
sheets, a few substeps (host numpy/scipy/ipctk and the host rigid world only, no Taichi)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("ipctk")
pytest.importorskip("scipy")

from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections  # noqa: E402
from simcli.solvers.fem.cloth.mesh_obstacles import body_mesh, cylinder_mesh, icosphere  # noqa: E402

SCENE = """\
version: 1
sim: {dim: 3, dt: 5.0e-3, substeps: 1, duration: 0.1, gravity: [0, 0, 0]}
domain: {lower: [-0.5, -0.5, -0.5], upper: [0.5, 0.5, 0.5]}
solvers:
  fem: {contact_distance: 2.0e-3}
rigid_bodies:
  - name: b
    morph: %(morph)s
    rho: 400
    velocity: [0, 0, -1.0]
    friction: 0.2
entities:
  - name: c
    material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 300, thickness: 1.0e-3, damping: 0.0, friction: 0.2}
    morph: {type: Rectangle, center: [0, 0, 0], size: [0.12, 0.12], resolution: 4}
"""


def _scene(tmp_path, morph):
    p = tmp_path / "cloth_rigid.yaml"
    p.write_text(textwrap.dedent(SCENE % dict(morph=morph)))
    return p


def _volume(V, T):
    return float(np.einsum("ij,ij->i", V[T[:, 0]], np.cross(V[T[:, 1]], V[T[:, 2]])).sum()) / 6.0


def test_body_meshes_are_closed_outward_and_close_to_the_shape():
    """The inscribed icosphere and prism: every edge shared by two triangles (closed), positive volume
    (outward), vertices on the surface, and the facets within contact_distance / 2 of it (so the volume is
    a little below the shape's)."""
    for V, T, exact in (
        (*icosphere(2), 4.0 / 3.0 * np.pi),
        (*cylinder_mesh([0.1, 0.2, 0.3], 0.05, 0.2, 0, 1e-3), np.pi * 0.05**2 * 0.2),
        (*cylinder_mesh([0, 0, 0], 0.05, 0.2, 1, 1e-3), np.pi * 0.05**2 * 0.2),
    ):
        e = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
        _, cnt = np.unique(e, axis=0, return_counts=True)
        assert (cnt == 2).all()
        vol = _volume(V - V.mean(axis=0), T)
        assert 0.95 * exact < vol < exact  # (level 2 icosphere: 0.966)
    V, _ = icosphere(3)
    np.testing.assert_allclose(np.linalg.norm(V, axis=1), 1.0, rtol=1e-12)

    class _M:  # a Sphere morph of radius 0.05 m: its facets' sag R a^2 / 6 below dhat / 2
        type, radius, center = "Sphere", 0.05, [0.0, 0.0, 0.0]

    class _RB:
        morph = _M()

    V, T = body_mesh(_RB(), None, None, 1e-3)
    c = V[T].mean(axis=1)
    assert 0.05 - np.linalg.norm(c, axis=1).min() < 0.5e-3


@pytest.mark.parametrize(
    "morph",
    [
        "{type: Box, center: [0.01, 0.02, 0.03], size: [0.04, 0.04, 0.04]}",
        "{type: Sphere, center: [0.01, 0.02, 0.03], radius: 0.02}",
    ],
)
def test_a_body_thrown_at_a_free_sheet_keeps_the_momentum_and_never_crosses_it(tmp_path, morph):
    """No gravity, no damping: a 1 m/s body hits a free 12 cm sheet. The body's 6 unknowns are in the cloth's
    Newton system; the reaction handed to the rigid world is minus the contact impulse the cloth received, so
    sheet + body keep their total momentum (to the Newton tolerance) and the world moves the body to where
    the solve put it; the body slows down, the sheet is carried; no segment-triangle crossing at any
    substep."""
    from simcli.rigid.world import release, world_for
    from tests.unit.test_fem_cloth import _solver

    s = _solver(_scene(tmp_path, morph))
    w = world_for(s.scene)
    assert s.world is w and s.collider_poses() is not None
    b = w.bodies[0]
    P0 = b.mass * b.state.v + s.mass @ s.v
    dt = 5e-3
    gap = 0.0
    for _ in range(14):
        s.substep(dt)
        w.step([s], dt)
        X = np.concatenate([s.x, s.vobs])
        T = np.concatenate([s.tris, s.mobst.T + s.n])
        assert edge_triangle_intersections(X, T) == []
        # the world's semi-implicit step puts the body where the cloth's Newton solve left it (rigid_dofs.py)
        gap = max(gap, float(np.linalg.norm(b.state.x - s.rdofs.end[0][0])))
    P = b.mass * b.state.v + s.mass @ s.v
    assert np.linalg.norm(P - P0) < 1e-4 * np.linalg.norm(P0)
    assert s.mass @ s.v[:, 2] < -0.1 * abs(P0[2])  # the sheet took a tenth of the momentum or more
    assert b.state.v[2] > -0.95
    assert gap < 1e-6, gap
    assert not w.frame_load[0, 2] == 0.0
    release(s.scene)


def test_a_cloth_starting_inside_a_rigid_body_is_refused_with_its_location(tmp_path):
    p = _scene(tmp_path, "{type: Box, center: [0, 0, 0.01], size: [0.04, 0.04, 0.04]}")
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 65, r.stderr
    assert f"{p}:" in r.stderr and "rigid_bodies.0 ('b', Box)" in r.stderr and "intersects" in r.stderr


class _Field:
    def __init__(self, a):
        self.a = np.array(a)

    def to_numpy(self):
        return self.a.copy()

    def from_numpy(self, a):
        self.a = np.array(a)


def test_fem_solid_surface_is_its_boundary_and_takes_the_reaction_as_momentum():
    """solid_obstacles.SolidSurface on a stand-in FEM solver (two tetrahedra sharing a face): its triangles
    are the 6 boundary faces (not the shared one), the target is the solver's positions once it has stepped
    to the substep's end (else extrapolated with its velocities), and the reaction dt f changes the solid's
    momentum sum m v by exactly dt sum f (a held component excepted)."""
    from simcli.solvers.fem.cloth.solid_obstacles import SolidSurface

    class _Fem:
        x0 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]])
        tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
        n = 5
        mass = np.array([1.0, 2.0, 2.0, 2.0, 1.0])
        time = 0.0

    fem = _Fem()
    fem.x, fem.v = _Field(fem.x0 + 0.1), _Field(np.ones((5, 3)))
    free = np.ones((5, 3))
    free[4, 2] = 0.0  # vertex 4 held in z
    fem.free_f = _Field(free)
    s = SolidSurface(fem)
    assert s.m == 5 and len(s.T) == 6
    np.testing.assert_allclose(s.target(0.01, 0.01), fem.x0 + 0.1 + 0.01)  # not stepped: extrapolated
    fem.time = 0.01
    np.testing.assert_allclose(s.target(0.01, 0.01), fem.x0 + 0.1)  # stepped: its own positions
    f = np.arange(15.0).reshape(5, 3)
    P0 = fem.mass @ fem.v.to_numpy()
    s.apply(f, 0.01)
    dP = fem.mass @ fem.v.to_numpy() - P0
    expect = 0.01 * f.sum(axis=0)
    expect[2] -= 0.01 * f[4, 2]
    np.testing.assert_allclose(dP, expect, rtol=1e-12)


def test_fem_cloth_beside_an_fem_solid_is_no_longer_said_to_pass_through(tmp_path):
    from simcli.scene.coupling import coupling_warnings
    from simcli.scene.loader import load_scene

    p = tmp_path / "s.yaml"
    p.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, duration: 0.1}
            domain: {lower: [0, 0, 0], upper: [0.3, 0.3, 0.3]}
            solvers:
              fem: {contact_distance: 2.0e-3, integrator: implicit}
            entities:
              - name: block
                material: {type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000}
                morph: {type: Box, lower: [0.1, 0.1, 0.0], upper: [0.2, 0.2, 0.1]}
              - name: cloth
                material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 300, thickness: 1.0e-3}
                morph: {type: Rectangle, center: [0.15, 0.15, 0.14], size: [0.2, 0.2], resolution: 4}
            """
        )
    )
    assert not [w for w in coupling_warnings(load_scene(p)) if "FEM.Cloth" in w]


def test_a_cloth_starting_inside_an_fem_solid_is_refused_with_its_location(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, duration: 0.1}
            domain: {lower: [0, 0, 0], upper: [0.3, 0.3, 0.3]}
            solvers:
              fem: {contact_distance: 2.0e-3, integrator: implicit}
            entities:
              - name: block
                material: {type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000}
                morph: {type: Box, lower: [0.1, 0.1, 0.0], upper: [0.2, 0.2, 0.1]}
              - name: cloth
                material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 300, thickness: 1.0e-3}
                morph: {type: Rectangle, center: [0.15, 0.15, 0.09], size: [0.2, 0.2], resolution: 4}
            """
        )
    )
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 65, r.stderr
    assert f"{p}:12:" in r.stderr and "inside the FEM solid 'block'" in r.stderr


def test_resume_with_a_rigid_body_equals_the_uninterrupted_run(tmp_path):
    """A sheet landing on a free Box body that rests on the floor: the cloth's checkpoint holds where its
    solve left the body (rigid_end) and the obstacle vertices, so a resumed run writes the same frames (to
    the last bits of the body's state: see below)."""
    import h5py

    scene = tmp_path / "cloth_body.yaml"
    scene.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.08}
            domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 0.5]}
            solvers:
              fem: {contact_distance: 2.0e-3}
            rigid_bodies:
              - name: b
                morph: {type: Box, center: [0, 0, 0.05], size: [0.1, 0.1, 0.1]}
                rho: 300
                friction: 0.3
            entities:
              - name: a
                material:
                  {type: FEM.Cloth, E: 1.0e5, rho: 200, thickness: 1.0e-3, friction: 0.3, damping: 0.5}
                morph: {type: Rectangle, center: [0.01, 0, 0.106], size: [0.2, 0.2], resolution: 4}
                velocity: [0.1, 0, -0.5]
            output: {every: 1, formats: [hdf5]}
            checkpoint: {every: 2, keep: 10}
            """
        )
    )
    out = tmp_path / "out"

    def run(*extra):
        return subprocess.run(
            [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(out), "-q", *extra],
            capture_output=True,
            text=True,
            timeout=300,
        )

    r = run()
    assert r.returncode == 0, r.stderr
    keys = (
        "entities/a/position",
        "entities/a/velocity",
        "rigid_bodies/b/position",
        "rigid_bodies/b/velocity",
    )
    with h5py.File(out / "sim.h5", "r") as f:
        full = {k: f[k][()] for k in keys}
        assert f["rigid_bodies/b/force"][()][:, 2].min() < -0.05  # the sheet landed on the body (pushes down)
    for p in sorted((out / "checkpoints").glob("ckpt_*.npz"))[2:]:  # resume from the one at step 4
        p.unlink()
    r = run("--resume")
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        for k, v in full.items():
            # (the body's reaction is a sum of ipctk's parallel per-pair gradients: its order, and so the last
            # bit, varies from run to run, as two uninterrupted runs show; the cloth here is bit for bit)
            np.testing.assert_allclose(f[k][()], v, rtol=0, atol=1e-12, err_msg=k)


def test_a_held_moving_body_pushes_a_pinned_sheet_and_never_crosses_it(tmp_path):
    """A body with all six dofs held (fixed_dofs) at 1 m/s downwards over a sheet pinned at two sides: the
    held dofs are a Dirichlet step of the cloth's Newton system (like moving pins), so the cloth meets the
    body where the rigid world moves it: the sheet is pushed down with the body, the world reads a non-zero
    reaction, and no segment-triangle crossing at any substep."""
    from simcli.rigid.world import release, world_for
    from tests.unit.test_fem_cloth import _solver

    p = tmp_path / "held.yaml"
    p.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.06}
            domain: {lower: [-0.3, -0.3, 0], upper: [0.3, 0.3, 0.5]}
            solvers:
              fem: {contact_distance: 2.0e-3}
            rigid_bodies:
              - name: ram
                morph: {type: Box, center: [0, 0, 0.235], size: [0.06, 0.06, 0.06]}
                rho: 200
                velocity: [0, 0, -1.0]
                fixed_dofs: [x, y, z, rx, ry, rz]
            entities:
              - name: sheet
                material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 300, thickness: 1.0e-3, damping: 3.0}
                morph: {type: Rectangle, center: [0, 0, 0.2], size: [0.3, 0.3], resolution: 6}
                fixed:
                  - {type: Box, lower: [-0.16, -0.16, 0.19], upper: [-0.14, 0.16, 0.21]}
                  - {type: Box, lower: [0.14, -0.16, 0.19], upper: [0.16, 0.16, 0.21]}
            """
        )
    )
    s = _solver(p)
    w = world_for(s.scene)
    b = w.bodies[0]
    dt = 1e-2
    fz = 0.0
    for k in range(5):
        s.substep(dt)
        w.step([s], dt)
        X = np.concatenate([s.x, s.vobs])
        T = np.concatenate([s.tris, s.mobst.T + s.n])
        assert edge_triangle_intersections(X, T) == []
        # the held body is where the world moved it, in the cloth's contact too
        np.testing.assert_allclose(b.state.x, [0, 0, 0.235 - (k + 1) * dt], atol=1e-12)
        np.testing.assert_allclose(s.rdofs.end[0][0], b.state.x, atol=1e-9)
        fz = max(fz, float(w.frame_load[0, 2]))
    bottom = 0.205 - 5 * dt  # 0.155 m: 4.5 cm below the sheet's rest plane
    assert s.x[:, 2].min() < bottom + 1e-3  # the sheet was pushed down with the body (not passed through)
    assert fz > 0.0  # the sheet pushes the body up: a reaction the world reads
    release(s.scene)


@pytest.mark.slow  # compiles the FEM solid's implicit kernels in a subprocess: about 20 s
def test_fem_solid_and_a_moving_convex_collider_beside_a_cloth_run(tmp_path):
    """A moving Sphere collider (not a Mesh) with an FEM solid beside a cloth: the solid's surface step and
    the collider's motion share a Dirichlet step (this crashed with a TypeError once)."""
    p = tmp_path / "s.yaml"
    p.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.02}
            domain: {lower: [0.0, 0.0, 0.0], upper: [0.3, 0.3, 0.3], boundary: {type: slip}}
            colliders:
              - {name: mover, type: Sphere, center: [0.02, 0.02, 0.25], radius: 0.01,
                 motion: {linear_velocity: [0.1, 0, 0]}}
            solvers:
              fem: {contact_distance: 2.0e-3, resolution: 8, integrator: implicit}
            entities:
              - name: block
                material: {type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000, model: stable_neohookean}
                morph: {type: Box, lower: [0.1, 0.1, 0.0], upper: [0.2, 0.2, 0.1]}
              - name: cloth
                material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 300, thickness: 1.0e-3}
                morph: {type: Rectangle, center: [0.15, 0.15, 0.14], size: [0.2, 0.2], resolution: 4}
            output: {every: 1, formats: [hdf5]}
            """
        )
    )
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(p), "-o", str(tmp_path / "out")],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr


def test_a_cloth_crossing_an_fem_solid_from_a_tet_mesh_file_is_refused_with_its_location(tmp_path):
    """An FEM solid given as a Mesh morph (a .msh of tetrahedra): its boundary is checked against the cloth at
    validate (this passed validate and then failed in the run's PSD projection)."""
    meshio = pytest.importorskip("meshio")
    from simcli.geometry.tetmesh import box_tets

    tm = box_tets([0.1, 0.1, 0.0], [0.2, 0.2, 0.1], 20)
    meshio.write(
        tmp_path / "block.msh",
        meshio.Mesh(np.asarray(tm.x), [("tetra", np.asarray(tm.tets))]),
        file_format="gmsh22",
    )
    p = tmp_path / "s.yaml"
    scene = """\
        version: 1
        sim: {dim: 3, dt: 1.0e-2, duration: 0.1}
        domain: {lower: [0, 0, 0], upper: [0.3, 0.3, 0.3]}
        solvers:
          fem: {contact_distance: 2.0e-3, integrator: implicit}
        entities:
          - name: block
            material: {type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000}
            morph: {type: Mesh, file: block.msh}
          - name: cloth
            material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 300, thickness: 1.0e-3}
            morph: {type: Rectangle, center: [0.15, 0.15, %s], size: [0.2, 0.2], resolution: 4}
        """
    p.write_text(textwrap.dedent(scene % "0.09"))
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 65, r.stderr
    assert f"{p}:12:" in r.stderr and "the FEM solid 'block' (entities.0, Mesh)" in r.stderr
    p.write_text(textwrap.dedent(scene % "0.14"))  # 4 cm above it: valid
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr


def test_a_fast_spinning_body_dropped_on_a_pinned_sheet_never_crosses_it(tmp_path):
    """An 8 x 2 x 2 cm Box spinning at 60 rad/s (0.6 rad a 10 ms step) dropped on a pinned sheet: the body's
    trial state is its exact rotation, on an arc away from the chord the Newton step's CCD took (by about
    r theta^2 / 8 = 2 mm); the line search checks the straight path to the state it accepts, so no
    body-edge/cloth-triangle crossing at any substep (8 from the fourth substep when only the chord was
    checked)."""
    from simcli.rigid.world import release, world_for
    from tests.unit.test_fem_cloth import _solver

    p = tmp_path / "spin.yaml"
    p.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.3, gravity: [0, 0, -9.81]}
            domain: {lower: [-0.5, -0.5, -0.5], upper: [0.5, 0.5, 0.5]}
            solvers:
              fem: {contact_distance: 2.0e-3}
            rigid_bodies:
              - name: b
                morph: {type: Box, center: [0.0, 0.0, 0.016], size: [0.08, 0.02, 0.02]}
                rho: 400
                velocity: [0, 0, -0.5]
                angular_velocity: [60, 0, 0]
                friction: 0.0
            entities:
              - name: c
                material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 300, thickness: 1.0e-3, damping: 0.0}
                morph: {type: Rectangle, center: [0, 0, 0], size: [0.16, 0.16], resolution: 12}
                fixed:
                  - {type: Box, lower: [-0.09, -0.09, -0.01], upper: [-0.07, 0.09, 0.01]}
                  - {type: Box, lower: [0.07, -0.09, -0.01], upper: [0.09, 0.09, 0.01]}
            """
        )
    )
    s = _solver(p)
    w = world_for(s.scene)
    for _ in range(5):
        s.substep(1e-2)
        w.step([s], 1e-2)
        X = np.concatenate([s.x, s.vobs])
        T = np.concatenate([s.tris, s.mobst.T + s.n])
        assert edge_triangle_intersections(X, T) == []
    assert s.x[:, 2].min() < -5e-3  # the body reached and pushed the sheet
    release(s.scene)
