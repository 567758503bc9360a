"""Coulomb friction of MPM at a wall and at a collider (issue 19): the issue's block, a 2D
neo-Hookean block (E 1e6, 0.1 x 0.05 m) launched at 1 m/s on a surface with friction 0.5, slides
v0^2 / (2 mu g) in v0 / (mu g). Before the fix it stopped after 0.065 m (a frictional slip wall
held the rocking block's back edge in tension while its front took up to 5x its weight)."""

import numpy as np
import pytest

from tests.physics.test_mpm import G, box, elastic, make_body, make_scene


@pytest.mark.parametrize("where", ["wall", "plane"])
def test_launched_block_slides_coulombs_distance_in_coulombs_time(ti_f32, where):
    from simcli.solvers.mpm import MPMSolver

    mu, v0, h, y0 = 0.5, 1.0, 1e-4, 0.0 if where == "wall" else 0.025
    lo, hi = (0.02, y0), (0.12, y0 + 0.05)
    kw = {"faces": {"y-": {"type": "slip", "friction": mu}}} if where == "wall" else {}
    colliders = (
        []
        if where == "wall"
        else [{"type": "Plane", "point": [0.0, y0], "normal": [0.0, 1.0], "boundary": "slip", "friction": mu}]
    )
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [0.3, 0.1], **kw},
        colliders=colliders,
        solvers={"mpm": {"grid_density": 128}},
        entities=[
            {
                "name": "b",
                "material": elastic("neohooken", E=1e6, nu=0.3),
                "morph": box(lo, hi),
                "velocity": [v0, 0.0],
            }
        ],
    )
    solver = MPMSolver(scene, [make_body(scene.entities[0], lo, hi, 0.0039)])
    solver.build()
    x0 = solver.entity_arrays("b", ["position"])["position"][:, 0].mean()
    t_stop, t_coulomb = None, v0 / (mu * G)
    ts, vs = [], []
    for k in range(1, 3001):
        solver.substep(h)
        if k % 50 == 0:
            v = float(solver.entity_arrays("b", ["velocity"])["velocity"][:, 0].mean())
            ts.append(k * h)
            vs.append(v)
            if 0.1 * v0 < v < 0.6 * v0:
                # uniform deceleration: the velocity is on Coulomb's line within 3% of v0
                assert v == pytest.approx(v0 - mu * G * k * h, abs=0.03 * v0), k * h
    ts, vs = np.array(ts), np.array(vs)
    sel = (vs > 0.1 * v0) & (vs < 0.6 * v0)
    slope, icpt = np.polyfit(ts[sel], vs[sel], 1)
    t_stop = -icpt / slope
    a = solver.entity_arrays("b", ["position", "velocity"])
    assert abs(a["velocity"][:, 0].mean()) < 0.01 * v0  # stopped
    assert a["position"][:, 0].mean() - x0 == pytest.approx(v0**2 / (2 * mu * G), rel=0.03)
    assert t_stop == pytest.approx(t_coulomb, rel=0.03)
