"""SPH colliders in prescribed motion and the loads on named colliders (issue 19): a piston pushing water
lets no particle in and is pushed back; a still named collider reads the liquid's push on it, the same
impulse (to round-off) that it gave the liquid in a substep. (The hydrostatic force and the paddle
are validation cases: configs/validation/sph_collider_hydrostatic*, sph_piston*, sph_paddle_water.)"""

import numpy as np
import pytest

from tests.physics.test_sph import make


def _scene(solver, colliders, water=((0.04, 0.0), (0.3, 0.08)), g=-9.81):
    return {
        "sim": {"dim": 2, "dt": 2e-3, "substeps": 1, "gravity": [0.0, g]},
        "domain": {"lower": [0, 0], "upper": [0.3, 0.15]},
        "colliders": colliders,
        "solvers": {"sph": {"particle_size": 0.01, "pressure_solver": solver}},
        "entities": [
            {
                "name": "water",
                "material": {"type": "SPH.Liquid", "mu": 0.05},
                "morph": {"type": "Box", "lower": list(water[0]), "upper": list(water[1])},
            }
        ],
    }


PISTON = {
    "name": "piston",
    "type": "Box",
    "lower": [0.0, -0.05],
    "upper": [0.04, 0.2],
    "motion": {"linear_velocity": [0.5, 0.0]},
}


@pytest.mark.parametrize("solver", ["DFSPH", pytest.param("WCSPH", marks=pytest.mark.slow)])
def test_moving_piston_lets_no_particle_in_and_is_pushed_back(ti_f32, solver):
    from simcli.colliders import _collider_spec, sdf_np
    from simcli.motion import collider_motion
    from simcli.scene.models import Scene

    s, _ = make(_scene(solver, [PISTON]))
    scene = Scene.model_validate(_scene(solver, [PISTON]))
    spec, motion = _collider_spec(scene.colliders[0], 2), collider_motion(scene.colliders[0], 2)
    dt, steps, deepest, J = 1e-3, 120, 0.0, np.zeros(5)
    for k in range(steps):
        s.substep(dt)
        if k % 10 == 9:
            x = s.entity_arrays("water", ["position"])["position"].astype(np.float64)
            phi = sdf_np(spec, motion.pose((k + 1) * dt).to_body(x))
            deepest = max(deepest, -float(phi.min()))
            J += s.collider_loads()["piston"]
    assert s.time == pytest.approx(steps * dt)
    assert deepest < 1e-3 * 0.01  # none inside the moved piston (f32 round-off of the pose)
    force = J[:2] / (steps * dt)
    assert np.isfinite(J).all()
    # the water resists the piston: pushed back along -x, by more than its hydrostatic push (the
    # piston accelerates the water), and much less than the water's weight times 10
    hydro = 1000 * 9.81 * 0.08**2 / 2
    assert -10 * 1000 * 0.26 * 0.08 * 9.81 < force[0] < -0.5 * hydro
    # the piston's front pushed the water: every particle stays right of its face
    x = s.entity_arrays("water", ["position"])["position"]
    assert x[:, 0].min() >= 0.04 + 0.5 * steps * dt - 1e-5


@pytest.mark.parametrize("solver", ["DFSPH", pytest.param("WCSPH", marks=pytest.mark.slow)])
def test_still_named_collider_load_is_the_impulse_it_gave(ti_f32, solver):
    """No gravity, no viscosity (whose m_j / rho_j pair weights are not symmetric where densities differ),
    f64: a block of water thrown at a named Box at 1 m/s. Over one substep the load on the collider is
    minus the change of the water's momentum (nothing else acts on it: no wall in reach)."""
    wall = {"name": "wall", "type": "Box", "lower": [0.2, 0.0], "upper": [0.25, 0.15]}
    d = _scene(solver, [wall], water=((0.06, 0.04), (0.19, 0.11)), g=0.0)
    d["sim"]["precision"] = "f64"
    d["entities"][0]["material"]["mu"] = 0.0
    s, bodies = make(d)
    s.v.from_numpy(np.tile(np.array([1.0, 0.0]), (s.n, 1)))
    for _ in range(15 if solver == "WCSPH" else 5):  # WCSPH: until the front is compressed
        s.substep(1e-3)
    s.collider_loads()
    m = s.mass.to_numpy()
    p0 = (m[:, None] * s.v.to_numpy()).sum(axis=0)
    s.substep(1e-3)
    p1 = (m[:, None] * s.v.to_numpy()).sum(axis=0)
    J = s.collider_loads()["wall"]
    assert J[0] > 1e-3  # the water pushes the wall along +x (impulse of a substep [N s per m])
    np.testing.assert_allclose(J[:2], -(p1 - p0), rtol=1e-6, atol=1e-6 * J[0])


def test_cells_marked_in_reach_of_a_turning_paddle_hold_every_boundary_neighbour(ti_f32):
    """With a collider in motion the density pass scans boundary particles only from the cells marked in
    reach of one (the walls' cells, kept from the build, and those within reach of a moving boundary
    particle, marked every substep): every liquid particle with a boundary particle within the kernel's
    support sits in a marked cell, and the liquid far from the paddle and the walls is not marked (it skips
    the scan, as with still walls)."""
    paddle = {
        "name": "paddle",
        "type": "Box",
        "lower": [0.3, 0.1],
        "upper": [0.42, 0.115],
        "motion": {"angular_velocity": [12.566370614359172]},
    }
    d = _scene("DFSPH", [paddle], water=((0.0, 0.0), (0.72, 0.2)))
    d["domain"] = {"lower": [0, 0], "upper": [0.72, 0.3]}
    s, _ = make(d)
    for k in range(60):
        s.substep(1e-3)
        if k % 20 != 19:
            continue
        x = s.x.to_numpy()[: s.n].astype(np.float64)
        bx = s.bx.to_numpy()[: s.nbp].astype(np.float64)
        near = s.bnear.to_numpy()[s.grid.cell_index_np(x)] != 0
        from scipy.spatial import cKDTree

        dist, _ = cKDTree(bx).query(x, distance_upper_bound=s.support)
        in_reach = np.isfinite(dist) & (dist < s.support)
        assert in_reach.sum() > 100
        assert near[in_reach].all()  # never a boundary neighbour missed
        assert (~near).sum() > 0.2 * s.n  # the bulk between the paddle and the walls skips the scan
