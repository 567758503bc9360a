"""Maths of the PBD solver: dihedral angle and its gradient, rest angles of a folded sheet, the graph
colouring behind the Gauss-Seidel sweeps, meshes of the Rectangle and Line morphs, and one XPBD
distance-constraint update against its closed form."""

import numpy as np
import pytest

from simcli.scene.morphs import LineShape, RectangleShape
from simcli.solvers.pbd.topology import (
    bending_quads,
    colour,
    dihedral_angles,
    dihedral_gradient,
    line_vertices,
    rectangle_mesh,
    unique_edges,
)


def test_dihedral_gradient_matches_finite_differences_and_sums_to_zero():
    rng = np.random.default_rng(1)
    q = np.array([[0, 1, 2, 3]])
    for _ in range(20):
        X = rng.normal(size=(4, 3))
        g = dihedral_gradient(*X)
        fd = np.zeros((4, 3))
        h = 1e-6
        for i in range(4):
            for k in range(3):
                Xp, Xm = X.copy(), X.copy()
                Xp[i, k] += h
                Xm[i, k] -= h
                fd[i, k] = (dihedral_angles(Xp, q) - dihedral_angles(Xm, q))[0] / (2 * h)
        assert np.allclose(g, fd, atol=1e-6 * max(1.0, np.abs(fd).max()))
        assert np.abs(g.sum(axis=0)).max() < 1e-12 * max(1.0, np.abs(g).max())  # no net force


@pytest.mark.parametrize("fold_deg", [30.0, 90.0, 150.0, -60.0])
def test_rest_angle_of_a_folded_sheet(fold_deg):
    """A sheet folded along x = 0 by an angle: the interior edges on the fold have that dihedral angle
    (signed), all other interior edges 0 (flat); Genesis takes every rest angle as flat."""
    m = RectangleShape(type="Rectangle", center=[0, 0, 0], size=[1.0, 0.5], resolution=[4, 2])
    x, tris = rectangle_mesh(m)
    a = np.radians(fold_deg)
    xf = x.copy()
    right = x[:, 0] > 1e-12
    xf[right, 0] = x[right, 0] * np.cos(a)
    xf[right, 2] = x[right, 0] * np.sin(a)
    quads = bending_quads(tris)
    theta = dihedral_angles(xf, quads)
    on_fold = np.all(np.abs(x[quads[:, 2:], 0]) < 1e-12, axis=1)
    assert on_fold.sum() == 2  # the two interior edges lying on x = 0
    assert np.allclose(np.abs(theta[on_fold]), abs(a), atol=1e-12)
    assert len(set(np.sign(theta[on_fold]).tolist())) == 1  # consistently oriented: one sign
    assert np.allclose(theta[~on_fold], 0.0, atol=1e-12)
    assert np.allclose(dihedral_angles(x, quads), 0.0, atol=1e-12)


def test_rectangle_mesh_counts_and_area():
    m = RectangleShape(
        type="Rectangle", center=[0.1, 0.2, 0.5], size=[2.0, 1.0], resolution=[10, 5], normal=[0, 1, 0]
    )
    x, tris = rectangle_mesh(m)
    assert x.shape == (66, 3) and tris.shape == (100, 3)
    area = 0.5 * np.linalg.norm(
        np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]), axis=1
    )
    assert area.sum() == pytest.approx(2.0)
    assert np.allclose(x[:, 1], 0.2)  # in the plane of its normal
    assert len(unique_edges(tris)) == 10 * 6 + 11 * 5 + 50  # rows, columns, one diagonal per cell


def test_line_vertices_at_equal_arc_length():
    m = LineShape(type="Line", points=[[0, 0, 0], [1, 0, 0], [1, 1, 0]], segments=8)
    x = line_vertices(m)
    seg = np.linalg.norm(np.diff(x, axis=0), axis=1)
    assert x.shape == (9, 3) and np.allclose(seg, 0.25)


def test_colouring_separates_constraints_sharing_a_vertex():
    m = RectangleShape(type="Rectangle", center=[0, 0, 0], size=[1.0, 1.0], resolution=12)
    x, tris = rectangle_mesh(m)
    for cons in (unique_edges(tris), bending_quads(tris)):
        order, off = colour(cons, len(x))
        assert sorted(order.tolist()) == list(range(len(cons)))
        for c in range(len(off) - 1):
            block = cons[order[off[c] : off[c + 1]]].reshape(-1)
            assert len(np.unique(block)) == block.size  # no vertex twice in one colour
        assert len(off) - 1 <= 2 * cons.shape[1] * 4  # a handful of colours, not one per constraint


def test_single_distance_constraint_xpbd_update(ti_f32):
    """One substep, one iteration, no gravity: a 1 kg vertex on a constraint of rest length 1 to a pinned
    vertex, stretched to 1.5: dlambda = -C / (w + alpha~), so C drops to C alpha~ / (w + alpha~), and
    lambda / dt^2 is the spring force -C_new / compliance."""
    from simcli.scene.models import Scene
    from simcli.solvers.pbd.solver import PBDSolver

    compliance, dt = 1e-3, 1e-2
    rho = 2.0 / (np.pi * 0.05**2)
    scene = Scene.model_validate(
        {
            "sim": {"dt": dt, "substeps": 1, "gravity": [0, 0, 0]},
            "domain": {"lower": [-2, -2, -2], "upper": [2, 2, 2]},
            "solvers": {"pbd": {"stretch_iterations": 1, "collisions": False}},
            "entities": [
                {
                    "name": "s",
                    "material": {
                        "type": "PBD.Elastic",
                        "rho": rho,
                        "stretch_compliance": compliance,
                        "bending_compliance": None,
                        "initial_stretch": [1.5, 1, 1],
                    },
                    "morph": {"type": "Line", "points": [[0, 0, 0], [1, 0, 0]], "radius": 0.05},
                    "fixed": {"type": "Sphere", "center": [0, 0, 0], "radius": 0.01},
                }
            ],
        }
    )
    s = PBDSolver(scene, [])
    s.build()
    assert s.inv_mass.tolist() == pytest.approx([0.0, 1.0])
    s.substep(dt)
    x = s.x.to_numpy().astype(np.float64)
    at = compliance / dt**2
    c_new = 0.5 * at / (1.0 + at)
    assert np.linalg.norm(x[1] - x[0]) - 1.0 == pytest.approx(c_new, rel=1e-5)
    lam = s.stretch.f_lam.to_numpy()[0]
    assert lam / dt**2 == pytest.approx(-c_new / compliance, rel=1e-4)
    # the spring pulls the pinned vertex towards +x: the support holds it back with the spring force
    r = s.entity_arrays("s", ["reaction"])["reaction"]
    assert r[0, 0] == pytest.approx(-c_new / compliance, rel=1e-4) and r[1] == pytest.approx([0, 0, 0])
