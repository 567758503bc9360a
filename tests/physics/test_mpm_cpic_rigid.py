"""CPIC for free rigid bodies (issue 20; docs/RIGID.md, CPIC bodies): a Box rigid body with ``cpic: true``
is a CPIC collider of the MPM solver whose pose the rigid world integrates, and the impulse of the CPIC
exchange (the incompatible pairs' momentum, the non-crossing projection, the node band) is the body's load:
the coupling is two-way and conserves momentum. Bad input: exit 65 with the key's location."""

import numpy as np
import pytest

from tests.physics.test_mpm import box, elastic, make_body, make_scene


def test_a_disk_thrown_at_a_free_cpic_plate_body_pushes_it_and_keeps_momentum(ti_f32):
    """No gravity: an elastic disk (a square block, 0.14 m) at 1.5 m/s hits a free plate half a cell thick
    (rho 3000): the plate is pushed away, the material's momentum plus the plate's stays what it was, the
    total kinetic energy does not grow and no particle crosses the plate's mid-plane."""
    from simcli.rigid.world import release, world_for
    from simcli.solvers.mpm import MPMSolver

    lo, hi = (0.12, 0.22), (0.26, 0.36)
    ent = {"name": "d", "material": elastic(E=2e4), "morph": box(lo, hi), "velocity": [1.5, 0.2]}
    plate = {"name": "plate", "morph": box((0.3, 0.1), (0.31, 0.5)), "rho": 3000.0, "cpic": True}
    scene = make_scene(
        sim={"dim": 2, "gravity": [0.0, 0.0]},
        domain={"lower": [0.0, 0.0], "upper": [0.8, 0.6]},
        solvers={"mpm": {"grid_density": 50}},
        entities=[ent],
        rigid_bodies=[plate],
    )
    try:
        s = MPMSolver(scene, [make_body(scene.entities[0], lo, hi, 0.01)])
        s.build()
        w = world_for(scene)
        b = w.bodies[0]
        m = s.mass.to_numpy().astype(np.float64)

        def totals():
            v = s.v.to_numpy().astype(np.float64)
            p = (m[:, None] * v).sum(axis=0) + b.mass * b.state.v
            e = 0.5 * (m * (v * v).sum(axis=1)).sum() + 0.5 * b.mass * b.state.v @ b.state.v
            return p, e + 0.5 * b.inertia[2, 2] * b.state.w[2] ** 2

        p0, e0 = totals()
        dt = 5e-4
        for i in range(140):
            s.substep(dt)
            w.step([s], dt)
            x = s.x.to_numpy().astype(np.float64)
            xb = b.motion.pose(w.t).to_body(x)  # the plate's body frame (its centre at x = 0.305)
            assert xb[:, 0].max() < 0.305  # nobody across the plate's mid-plane
            p, e = totals()
            assert e <= e0 * (1 + 1e-5)  # the exchange never creates energy
        assert b.state.v[0] > 0.3  # the disk pushed the plate
        np.testing.assert_allclose(p, p0, atol=2e-3 * np.linalg.norm(p0))
    finally:
        release(scene)


@pytest.mark.parametrize(
    "body, extra, msg",
    [
        ("{type: Sphere, center: [0.6, 0.5], radius: 0.05}", "", "cpic: true is for Box bodies"),
        ("{type: Box, lower: [0.6, 0.3], upper: [0.605, 0.7]}", "  mpm: {transfer: flip}\n", "needs solvers"),
    ],
)
def test_cpic_bodies_where_it_does_not_apply_are_refused_with_their_location(tmp_path, body, extra, msg):
    from tests.cli.test_bad_input import _expect

    text = (
        "version: 1\nsim: {dim: 2, dt: 1.0e-3, duration: 0.01}\ndomain: {lower: [0, 0], upper: [1, 1]}\n"
        + ("solvers:\n" + extra if extra else "")
        + "entities:\n  - name: a\n    material: {type: MPM.Elastic, E: 3.0e5, nu: 0.2, rho: 1000}\n"
        "    morph: {type: Box, lower: [0.1, 0.1], upper: [0.3, 0.3]}\n"
        f"rigid_bodies:\n  - name: p\n    morph: {body}\n    rho: 1000\n    cpic: true\n"
    )
    line = 12 + (2 if extra else 0)
    _expect(tmp_path, text, f":{line}:", msg)
