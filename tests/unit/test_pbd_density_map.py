"""PBD.Liquid's density map of a Mesh rigid body (simcli.solvers.pbd.density_map): on a cube read from a
mesh it is the domain walls' half-space table on a face, and near the edges it counts what the Box body's
exact inclusion-exclusion counts (the tangent half-space it replaced counted twice that next to an edge)."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.ndimage import map_coordinates

from simcli.collider_mesh import build_sdf
from simcli.solvers.pbd.density_map import build_density_map
from simcli.solvers.pbd.liquid import wall_tables

ROOT = Path(__file__).resolve().parents[2]


def test_the_density_map_of_a_mesh_cube_is_the_box_s_wall_density():
    ps, h = 0.01, 0.02
    d, half, dhalf, quarter, _, _ = wall_tables(ps, h, 1.0)
    q = RegularGridInterpolator((d, d), quarter)
    c = SimpleNamespace(
        file=str(ROOT / "configs/meshes/cube.obj"),
        scale=0.06,
        rotate=(0, 0, 0),
        translate=(0, 0, 0),
        sdf_cell=0.005,
    )
    sdf = build_sdf(c, None, None)
    origin, cell, rho, grad = build_density_map(sdf, ps, h, 1.0, d, half)

    def at(x, fld=rho):
        return float(map_coordinates(fld, ((np.asarray(x, float) - origin) / cell)[:, None], order=1)[0])

    # the middle of the top face (z = 0.03): the wall table and its slope
    for dist in (0.0, 0.005, 0.0075, 0.01):
        assert abs(at([0, 0, 0.03 + dist]) - np.interp(dist, d, half)) <= 1e-6 * half[0]
    assert abs(at([0, 0, 0.035], grad[..., 2]) / np.interp(0.005, d, dhalf) - 1) < 0.05
    assert at([0, 0, 0.03 + 0.016]) < 1e-3 * half[0]  # beyond the lattice's reach
    # half a spacing above the top face, near the edge x = 0.03: the Box's half-space less the quarter-space
    # beyond the side face (within 6%; the tangent half-space is 1.9x at the edge)
    for inset in (0.0, 0.005, 0.01):
        box = np.interp(0.005, d, half) - q([[0.005, inset]])[0]
        assert abs(at([0.03 - inset, 0, 0.035]) / box - 1) < 0.06
    # outside the edge, 0.005 from both faces: the quarter-space (the map also counts the corners' octants)
    assert abs(at([0.035, 0, 0.035]) / q([[0.005, 0.005]])[0] - 1) < 0.15
    assert 0 < at([0.035, 0.035, 0.035]) < 0.1 * np.interp(0.005, d, half)
