"""MPM liquid at rest against a collider (issue 19): the collider's image (simcli.solvers.mpm.boundary,
``GridBoundary._image``) lets the liquid meet the surface with its bulk pressure, so that the force on a
named wall is rho g h^2 / 2 wherever the surface falls between the grid nodes. Without it the first free
nodes' kernels reached into empty nodes past the surface and the force read the pressure of a shallower
depth: -15% at 10 cells of depth with the surface on a node line, first order in dx."""

import pytest

from tests.physics.test_mpm import G, box, make_body, make_scene

LIQUID = {"type": "MPM.Liquid", "E": 1.0e6, "nu": 0.2, "rho": 1000.0, "viscous": True, "mu": 200.0}


@pytest.mark.parametrize("offset", [0.0, 0.5])
def test_settled_liquid_column_pushes_a_named_wall_with_its_hydrostatic_force(ti_f32, offset):
    from simcli.solvers.mpm import MPMSolver

    dx, h = 0.02, 0.2
    xw = 0.1 + offset * dx  # the wall's face: on a node line, or half a cell past it
    lo, hi = (0.0, 0.0), (xw, h)
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [0.2, 0.3]},
        colliders=[{"name": "wall", "type": "Box", "lower": [xw, -0.05], "upper": [0.25, 0.35]}],
        solvers={"mpm": {"grid_density": 50}},
        entities=[{"name": "w", "material": LIQUID, "morph": box(lo, hi)}],
    )
    s = MPMSolver(scene, [make_body(scene.entities[0], lo, hi, 0.01)])
    s.build()
    dt, n_settle, n_avg = 5e-4, 400, 400
    for _ in range(n_settle):
        s.substep(dt)
    s.collider_loads()  # discard the settling
    for _ in range(n_avg):
        s.substep(dt)
    force = s.collider_loads()["wall"][:2] / (n_avg * dt)
    assert force[0] == pytest.approx(1000.0 * G * h**2 / 2, rel=0.03)  # 196.2 N/m
    assert abs(force[1]) < 0.01 * force[0]  # a frictionless wall
