"""The frictionless collider's image acts only where the material is at the surface (issue 20): an MPM
liquid approaching a named frictionless Box across a gap gives it no impulse until it arrives (the image,
and the contact of the nodes inside the Box, fade with the gap between the surface and the material the
nodes gather: simcli.solvers.mpm.boundary, ``GridBoundary._fade``), and once it arrives the Box takes
the momentum the liquid loses. Before the fade the image carried material across a sub-cell gap (a
dropped floating body rested on a sparse layer and rode 23% high, docs/RIGID.md)."""

import numpy as np
import pytest

from tests.physics.test_mpm import box, make_body, make_scene

LIQUID = {"type": "MPM.Liquid", "E": 1.0e5, "nu": 0.2, "rho": 1000.0, "viscous": True, "mu": 1.0}


def test_liquid_approaching_a_frictionless_box_pushes_it_only_once_it_arrives(ti_f32):
    from simcli.solvers.mpm import MPMSolver

    dx, u = 0.02, 0.5
    y_face = 0.1 + 0.3 * dx  # the Box's lower face, 0.3 cell past a node line
    gap = 1.0 * dx  # between the liquid's top and the face at the start
    lo, hi = (0.04, y_face - gap - 0.04), (0.16, y_face - gap)
    scene = make_scene(
        sim={"dim": 2, "gravity": [0.0, 0.0]},
        domain={"lower": [0.0, 0.0], "upper": [0.2, 0.2]},
        colliders=[{"name": "lid", "type": "Box", "lower": [-0.05, y_face], "upper": [0.25, 0.25]}],
        solvers={"mpm": {"grid_density": 50}},
        entities=[{"name": "w", "material": LIQUID, "morph": box(lo, hi), "velocity": [0.0, u]}],
    )
    body = make_body(scene.entities[0], lo, hi, 0.01)
    s = MPMSolver(scene, [body])
    s.build()
    dt = 2e-4
    n_free = int(0.5 * gap / u / dt)  # the liquid covers half the gap: still 0.5 cell from the face
    for _ in range(n_free):
        s.substep(dt)
    top = s.entity_arrays("w", ["position"])["position"][:, 1].max()
    assert y_face - top > 0.4 * dx  # (the liquid has not arrived)
    assert np.all(s.collider_loads()["lid"][:2] == 0.0)  # no impulse across the gap
    for _ in range(int(3 * gap / u / dt)):
        s.substep(dt)
    impulse = s.collider_loads()["lid"][:2]  # [N s per m]
    m = float(body.mass.sum())
    v = s.entity_arrays("w", ["velocity"])["velocity"][:, 1]
    assert impulse[1] == pytest.approx(m * (u - v.mean()), rel=0.02)  # the momentum the liquid lost
    assert impulse[1] > 0.5 * m * u  # (it did arrive and was stopped)
