"""FEM.Cloth (simcli.solvers.fem.cloth): energy derivatives by finite differences, the bending model against
the plate energy, the intersection test, and small end-to-end checks (free fall, contact without
intersection, bad input). Host numpy/scipy/ipctk only (no Taichi)."""

from __future__ import annotations

import textwrap
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("ipctk")
pytest.importorskip("scipy")

from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections  # noqa: E402
from simcli.solvers.fem.cloth.model import ShellModel, mesh_problems  # noqa: E402
from simcli.solvers.fem.cloth.topology import rectangle_mesh  # noqa: E402


def _sheet(n=6, size=(1.0, 0.8)):
    m = SimpleNamespace(resolution=[n, n - 1], normal=[0, 0, 1], center=[0, 0, 0], size=list(size))
    return rectangle_mesh(m)


def _fd_grad(f, x, eps=1e-6):
    g = np.zeros_like(x)
    for i in range(x.shape[0]):
        for k in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, k] += eps
            xm[i, k] -= eps
            g[i, k] = (f(xp) - f(xm)) / (2 * eps)
    return g


@pytest.mark.parametrize("curved", [False, True])
def test_energy_gradient_matches_finite_differences(curved):
    X, t = _sheet()
    if curved:  # a curved rest shape: discrete-shell hinges instead of the quadratic model
        X[:, 2] = 0.2 * X[:, 0] ** 2
    mod = ShellModel(X, t, mu=3.0, lam_ps=2.0, thickness=0.1, D=0.7)
    assert (mod.quadratic is None) == curved
    x = X + 0.05 * np.random.default_rng(1).standard_normal(X.shape)
    e, g, _ = mod.energy_grad_hess(x, 1)
    gfd = _fd_grad(lambda y: mod.energy_grad_hess(y, 1)[0], x)
    assert np.abs(g - gfd).max() <= 1e-6 * np.abs(g).max()


def test_membrane_hessian_matches_finite_differences_where_convex():
    """In tension StVK's element Hessian is positive definite, so the projected Hessian is exact there."""
    X, t = _sheet(3)
    mod = ShellModel(X, t, mu=3.0, lam_ps=2.0, thickness=0.1, D=0.0)
    x = X * np.array([1.2, 1.15, 1.0])  # stretched: every triangle in tension
    _, _, H = mod.membrane(x, 2)
    import scipy.sparse as sp

    rows, cols = mod._rows_t, mod._cols_t
    K = sp.coo_matrix((H.ravel(), (rows, cols)), shape=(3 * len(x),) * 2).toarray()
    eps = 1e-6
    Kfd = np.zeros_like(K)
    for j in range(3 * len(x)):
        xp, xm = x.copy().ravel(), x.copy().ravel()
        xp[j] += eps
        xm[j] -= eps
        Kfd[:, j] = (
            mod.membrane(xp.reshape(-1, 3), 1)[1] - mod.membrane(xm.reshape(-1, 3), 1)[1]
        ).ravel() / (2 * eps)
    assert np.abs(K - Kfd).max() <= 1e-5 * np.abs(K).max()


def test_rigid_motion_costs_no_energy():
    X, t = _sheet()
    mod = ShellModel(X, t, mu=3.0, lam_ps=2.0, thickness=0.1, D=0.7)
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s, 0], [s * 0.6, c * 0.6, -0.8], [s * 0.8, c * 0.8, 0.6]])
    e, g, _ = mod.energy_grad_hess(X @ R.T + 0.3, 1)
    e_ref, g_ref, _ = mod.energy_grad_hess(X * 1.01, 1)  # 1 % stretch for scale
    assert e < 1e-6 * e_ref and np.abs(g).max() < 1e-6 * np.abs(g_ref).max()


@pytest.mark.parametrize("phi", [0.0, np.pi / 4, 0.3])
def test_bending_energy_of_a_cylinder_is_the_plate_energy_in_any_direction(phi):
    """D/2 kappa^2 per unit area: isotropic on the criss-cross mesh, within 4 % at 40 x 40 (the free edges'
    flux is first order: 0.90, 0.95, 0.975 at 10, 20, 40 cells along the bent direction)."""
    X, t = rectangle_mesh(
        SimpleNamespace(resolution=[40, 40], normal=[0, 0, 1], center=[0, 0, 0], size=[1, 1])
    )
    mod = ShellModel(X, t, mu=1.0, lam_ps=1.0, thickness=0.1, D=1.0)
    assert np.abs(mod.quadratic @ X).max() < 1e-9  # no bending force at rest
    d = np.array([np.cos(phi), np.sin(phi)])
    s, o = X[:, :2] @ d, X[:, :2] @ np.array([-d[1], d[0]])
    R = 1.0
    x = np.stack(
        [R * np.sin(s / R) * d[0] - o * d[1], R * np.sin(s / R) * d[1] + o * d[0], R * (1 - np.cos(s / R))], 1
    )
    eb = mod.energy_grad_hess(x, 1)[0] - mod.membrane(x, 1)[0]
    assert 0.96 <= eb / (0.5 / R**2) <= 1.0


def test_mesh_problems_name_degenerate_and_non_manifold():
    X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [2, 0, 0]], float)
    t = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4], [0, 1, 5]])
    msgs = mesh_problems(X, t)
    assert any("degenerate" in m for m in msgs) and any("non-manifold" in m for m in msgs)


def test_intersection_check_finds_a_crossing_and_nothing_on_a_flat_sheet():
    X, t = _sheet()
    assert edge_triangle_intersections(X, t) == []
    # a second triangle piercing the first
    X2 = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, -0.5], [0.3, 0.2, 0.5], [0.25, 0.4, 0.5]], float
    )
    hits = edge_triangle_intersections(X2, np.array([[0, 1, 2], [3, 4, 5]]))
    assert hits and abs(hits[0][2][2]) < 1e-12


def _scene(tmp_path, body: str):
    p = tmp_path / "cloth.yaml"
    p.write_text(textwrap.dedent(body))
    return p


BASE = """\
version: 1
sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: %(dur)s}
domain: {lower: [-1, -1, 0], upper: [1, 1, 1]}
%(col)s
solvers:
  fem: {contact_distance: %(dhat)s}
entities:
  - name: c
    material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 200, thickness: %(h)s}
    morph: {type: Rectangle, center: [0, 0, %(z)s], size: [0.4, 0.4], resolution: 6}
"""


def _solver(path):
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.cloth.solver import ClothSolver

    ld = load_scene(path)
    s = ClothSolver(ld.scene, [], scene_dir=ld.scene_dir)
    s.build()
    return s


def test_free_fall_is_exact_backward_euler(tmp_path):
    p = _scene(tmp_path, BASE % dict(dur=0.05, col="", dhat=1e-3, h=1e-3, z=0.5))
    s = _solver(p)
    for _ in range(5):
        s.substep(0.01)
    # backward Euler: v_k = -g k dt, z_k = z0 - g dt^2 k (k + 1) / 2
    assert s.v[:, 2] == pytest.approx(-9.81 * 0.05, rel=1e-4)  # to the Newton tolerance
    assert 0.5 - s.x[:, 2] == pytest.approx(9.81 * 1e-4 * 15, rel=1e-4)


def test_cloth_falls_onto_a_sphere_without_touching_it(tmp_path):
    col = "colliders:\n  - {type: Sphere, center: [0, 0, 0.3], radius: 0.1, friction: 0.3}"
    p = _scene(tmp_path, BASE % dict(dur=0.3, col=col, dhat=5e-3, h=1e-3, z=0.45))
    s = _solver(p)
    for _ in range(25):
        s.substep(0.01)
        d = np.linalg.norm(s.x - [0, 0, 0.3], axis=1) - 0.1
        assert d.min() > 0 and np.isfinite(s.x).all()
        assert edge_triangle_intersections(s.x, s.tris) == []
    # resting on it: inside the barrier's reach of the facet stand-off (the vertices keep sqrt(R^2 + r^2) - R
    # off the sphere so that no triangle dips into it; obstacles.Obstacles.set_facets), the faces outside
    off = s.obst.offsets[0]
    assert (d - off).min() < 5e-3
    from simcli.collider_mesh import mesh_distance

    assert float(mesh_distance(s.x, s.tris, np.array([[0, 0, 0.3]]))[0]) > 0.1
    assert s.x[:, 2].max() > 0.35  # held up by it


def _validate(path):
    import subprocess
    import sys

    return subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(path)], capture_output=True, text=True, timeout=120
    )


def test_bad_input_exits_65_with_location(tmp_path):
    p = _scene(tmp_path, BASE % dict(dur=0.1, col="", dhat=1e-3, h=5e-3, z=0.5))
    r = _validate(p)
    assert r.returncode == 65 and "thickness" in r.stderr and "cloth.yaml:" in r.stderr, r.stderr
    col = "colliders:\n  - {type: Sphere, center: [0, 0, 0.5], radius: 0.1}"
    p = _scene(tmp_path, BASE % dict(dur=0.1, col=col, dhat=1e-3, h=1e-3, z=0.5))
    r = _validate(p)
    assert r.returncode == 65 and "colliders.0" in r.stderr and "start inside" in r.stderr, r.stderr


def test_two_sheets_fall_onto_each_other_without_intersecting(tmp_path):
    """Self-contact between entities (ipctk barrier, CCD) with self friction, on the floor."""
    body = """\
    version: 1
    sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.2}
    domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 0.5]}
    solvers:
      fem: {contact_distance: 2.0e-3}
    entities:
      - name: a
        material: {type: FEM.Cloth, E: 1.0e5, rho: 200, thickness: 1.0e-3, friction: 0.3}
        morph: {type: Rectangle, center: [0, 0, 0.01], size: [0.2, 0.2], resolution: 5}
      - name: b
        material: {type: FEM.Cloth, E: 1.0e5, rho: 200, thickness: 1.0e-3, friction: 0.3}
        morph: {type: Rectangle, center: [0.03, 0.01, 0.03], size: [0.2, 0.2], resolution: 5}
    """
    s = _solver(_scene(tmp_path, body))
    for _ in range(9):
        s.substep(0.01)
        assert edge_triangle_intersections(s.x, s.tris) == [] and s.x[:, 2].min() > 0
    lo, up = s.x[: s.offsets[1]], s.x[s.offsets[1] :]
    inner = lambda p: np.all(np.abs(p[:, :2]) < 0.06, axis=1)  # noqa: E731  (inside both footprints)
    assert up[inner(up), 2].min() > lo[inner(lo), 2].max()  # lying on the lower sheet, not through it
    assert up[:, 2].max() < 0.02  # it has landed


def test_backward_euler_only_dissipates(tmp_path):
    """No gravity, no damping, one edge pinned, the rest thrown sideways: kinetic + elastic energy never
    grows from one substep to the next (backward Euler's numerical damping is the only loss)."""
    body = """\
    version: 1
    sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.1, gravity: [0, 0, 0]}
    domain: {lower: [-1, -1, 0], upper: [1, 1, 1]}
    solvers:
      fem: {contact_distance: 1.0e-3, newton_atol: 1.0e-6}
    entities:
      - name: c
        material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 200, thickness: 1.0e-3}
        morph: {type: Rectangle, center: [0, 0, 0.5], size: [0.3, 0.3], resolution: 5}
        velocity: [0, 0, 1.0]
        fixed: {type: Box, lower: [-0.16, -0.2, 0.4], upper: [-0.14, 0.2, 0.6]}
    """
    s = _solver(_scene(tmp_path, body))
    energy = []
    for _ in range(10):
        s.substep(0.01)
        w = s.model.energy_grad_hess(s.x, 1)[0]
        energy.append(0.5 * float(np.sum(s.mass[:, None] * s.v**2)) + w)
    assert energy[0] > 0 and all(b <= a * (1 + 1e-9) for a, b in zip(energy, energy[1:]))
    assert energy[-1] < energy[0]


EDGE_LOAD = """\
version: 1
sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.05, gravity: [0, 0, 0]}
domain: {lower: [-1, -1, -1], upper: [1, 1, 1]}
solvers:
  fem: {contact_distance: 3.0e-3, newton_atol: 1.0e-8, newton_tol: 1.0e-10}
entities:
  - name: c
    material:
      type: FEM.Cloth
      E: 1.0e5
      rho: 200
      thickness: 2.0e-3
      boundary_conditions: [%s]
    morph: {type: Rectangle, center: [0, 0, 0], size: [0.4, 0.2], resolution: [4, 2]}
"""


def test_edge_traction_is_the_stated_force_and_drives_momentum(tmp_path):
    """A free sheet (no gravity, no pins) loaded on one end edge: the loads sum to traction x width x
    thickness, and each backward-Euler substep adds that force x dt to the momentum (internal forces
    cancel)."""
    bc = "{region: {type: Box, lower: [0.19, -0.2, -0.1], upper: [0.21, 0.2, 0.1]}, traction: [0, 300, 500]}"
    s = _solver(_scene(tmp_path, EDGE_LOAD % bc))
    F = np.array([0.0, 300.0, 500.0]) * 0.2 * 2.0e-3  # traction x edge length x thickness [N]
    np.testing.assert_allclose(s.fext.sum(axis=0), F, rtol=1e-12)
    assert np.all(s.fext[np.abs(s.X[:, 0] - 0.2) > 1e-9] == 0)  # only the loaded edge's vertices
    for k in range(1, 4):
        s.substep(0.01)
        p = (s.mass[:, None] * s.v).sum(axis=0)
        np.testing.assert_allclose(p, F * 0.01 * k, rtol=1e-6, atol=1e-12)


def test_ramped_traction_grows_linearly_then_holds(tmp_path):
    """ramp_time: the load at a step's end is min(1, t / ramp_time) times the traction's (backward Euler),
    so the momentum gains sum_k F min(1, t_k / T) dt."""
    bc = (
        "{region: {type: Box, lower: [0.19, -0.2, -0.1], upper: [0.21, 0.2, 0.1]}, traction: [0, 300, 500], "
        "ramp_time: 0.025}"
    )
    s = _solver(_scene(tmp_path, EDGE_LOAD % bc))
    F = np.array([0.0, 300.0, 500.0]) * 0.2 * 2.0e-3
    impulse = np.zeros(3)
    for k in range(1, 5):
        s.substep(0.01)
        impulse += F * min(1.0, 0.01 * k / 0.025) * 0.01
        p = (s.mass[:, None] * s.v).sum(axis=0)
        np.testing.assert_allclose(p, impulse, rtol=1e-6, atol=1e-12)


def test_cloth_traction_takes_no_axes(tmp_path):
    bc = "{region: {type: Box, lower: [0.19, -0.2, -0.1], upper: [0.21, 0.2, 0.1]}, axes: [x]}"
    r = _validate(_scene(tmp_path, EDGE_LOAD % bc))
    assert r.returncode == 65, r.stderr
    assert "boundary_conditions" in r.stderr and "axes" in r.stderr, r.stderr


def test_compressed_triangles_keep_the_negative_curvature_their_inertia_covers():
    """membrane(..., inertia): a compressed triangle's Hessian is proj(H_e + D_e) - D_e. Where H_e + D_e is
    already positive semi-definite that is H_e itself (the exact Hessian, negative curvature kept); where
    not, H_e + D_e becomes the nearest PSD matrix, so the assembled matrix plus the inertia stays PSD; a
    triangle in tension is unchanged either way."""
    X, t = _sheet(3)
    exact = ShellModel(X, t, mu=3.0, lam_ps=2.0, thickness=0.1, D=0.0)
    x = X * np.array([0.8, 0.9, 1.0]) + 0.01 * np.random.default_rng(3).standard_normal(X.shape)
    _, _, H_clamped = exact.membrane(x, 2)  # without inertia: dP/dF clamped, as before
    _, _, H_big = exact.membrane(x, 2, inertia=np.full(len(x), 1e3))  # inertia covers everything
    _, _, H_none = exact.membrane(x, 2, inertia=np.zeros(len(x)))  # no inertia: the 9x9 clamp
    # the exact element Hessians, by finite differences of the element gradients
    eps = 1e-6
    for k in range(len(t)):
        Hfd = np.empty((9, 9))
        for c in range(9):
            xp, xm = x.copy(), x.copy()
            xp[t[k][c // 3], c % 3] += eps
            xm[t[k][c // 3], c % 3] -= eps
            gp = _element_grad(exact, xp, k)
            gm = _element_grad(exact, xm, k)
            Hfd[:, c] = (gp - gm) / (2 * eps)
        assert np.abs(H_big[k] - Hfd).max() <= 1e-5 * np.abs(Hfd).max()
        assert np.linalg.eigvalsh(H_none[k]).min() >= -1e-9 * np.abs(Hfd).max()
    lam = np.linalg.eigvalsh(H_big)
    assert lam.min() < -1e-6 * np.abs(lam).max()  # some compressed triangle had negative curvature: kept
    assert np.linalg.eigvalsh(H_clamped).min() >= -1e-9 * np.abs(lam).max()  # the old one dropped it


def _element_grad(mod, x, k):
    """Gradient of triangle k's membrane energy with respect to its 9 vertex coordinates."""
    sub = ShellModel(mod.X, mod.tris[k : k + 1], mu=3.0, lam_ps=2.0, thickness=0.1, D=0.0)
    _, g, _ = sub.membrane(x, 1)
    return g[mod.tris[k]].ravel()


def test_newton_vtol_stops_on_the_step_s_velocity(tmp_path):
    """solvers.fem.newton_vtol: Newton also stops when |p| / dt falls below it; off (0) by default. A sheet
    falling onto a sphere: fewer Newton steps with it, the same sheet within a millimetre."""
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.cloth.solver import ClothSolver

    p = tmp_path / "s.yaml"
    p.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.15}
            domain: {lower: [-1, -1, 0], upper: [1, 1, 1.5]}
            colliders:
              - {type: Sphere, center: [0, 0, 0.3], radius: 0.25, friction: 0.3}
            solvers:
              fem: {contact_distance: 2.0e-3}
            entities:
              - name: cloth
                material: {type: FEM.Cloth, E: 1.0e6, nu: 0.3, rho: 400, thickness: 5.0e-4, damping: 0.5}
                morph: {type: Rectangle, center: [0, 0, 0.6], size: [1.0, 1.0], resolution: 16}
            """
        )
    )
    out = {}
    for vtol in (0.0, 1.0e-2):
        sc = load_scene(p, [f"solvers.fem.newton_vtol={vtol}"]).scene
        assert sc.solvers.fem.newton_vtol == vtol
        s = ClothSolver(sc, [], scene_dir=None)
        s.build()
        for _ in range(15):
            s.substep(0.01)
        out[vtol] = (s.info()["newton_iterations"], s.x.copy())
        assert len(edge_triangle_intersections(s.x, s.tris)) == 0
    assert out[1.0e-2][0] < out[0.0][0]
    assert np.abs(out[1.0e-2][1] - out[0.0][1]).max() < 1.0e-3
