"""Stable fluids with colliders in prescribed motion (issue 19): a disk set moving through air at rest
receives its added-mass impulse in the first projection, pushes the air ahead of it along, and the
divergence stays at the solver's tolerance with the solid cells changing every substep."""

import numpy as np
import pytest


def _solver(scene_dict):
    from simcli.scene.models import Scene
    from simcli.solvers.sf.solver import SFSolver

    s = SFSolver(Scene.model_validate(scene_dict), [])
    s.build()
    return s


def test_moving_disk_added_mass_and_push(ti_f32):
    R, U, dt = 0.15, 1.0, 0.01
    s = _solver(
        {
            "sim": {"dim": 2, "dt": dt, "substeps": 1, "gravity": [0.0, 0.0]},
            "domain": {"lower": [0, 0], "upper": [2.0, 2.0], "boundary": {"type": "slip"}},
            "colliders": [
                {
                    "name": "disk",
                    "type": "Sphere",
                    "center": [1.0, 1.0],
                    "radius": R,
                    "motion": {"linear_velocity": [U, 0.0]},
                }
            ],
            "solvers": {"sf": {"resolution": 64, "pressure_solver": "mgpcg", "tolerance": 1e-6}},
            "entities": [{"name": "air", "material": {"type": "SF.Smoke", "rho": 1.0}}],
        }
    )
    s.substep(dt)
    J = s.collider_loads()["disk"]
    # added mass of a disk, rho pi R^2, raised by the walls of a channel of half-width W by about
    # 1 + (pi^2 / 3) (R / W)^2 (a cylinder between two walls; the end walls 0.85 m away add a little)
    m_added = np.pi * R**2 * (1.0 + np.pi**2 / 3.0 * (R / 1.0) ** 2)
    assert J[0] == pytest.approx(-m_added * U, rel=0.1)
    assert abs(J[1]) < 1e-3 * abs(J[0])
    for _ in range(9):
        s.substep(dt)
    assert s.projection.converged(dt)
    # the disk has moved 0.1 m: the solid cells follow it, the air just ahead moves along +x
    solid = s.layout.flags[1:-1, 1:-1] == 1
    xc = np.stack([c.ravel() for c in s.layout.cell_centres()], axis=1)
    ds = np.linalg.norm(xc - [1.1, 1.0], axis=1).reshape(s.layout.n)
    assert solid[ds < R - 0.04].all() and not solid[ds > R + 0.04].any()
    u = s.cell_velocity()[..., 0]
    ahead = (ds > R + 0.02) & (ds < R + 0.06) & (xc[:, 0].reshape(s.layout.n) > 1.1 + R)
    assert u[ahead].mean() > 0.3 * U
