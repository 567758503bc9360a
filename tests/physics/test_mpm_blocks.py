"""MPM's grid work over the block list (simcli/solvers/mpm/blocks.py) gives the same numbers, bit for bit,
as the sweep over the particles' node box, while visiting fewer nodes when the material is spread out.

Two bodies far apart (the box between them is mostly empty), a frictionless sphere collider (its image
reads the P2G copies around the nodes), fixed particles, 2 and 3 dimensions, APIC and FLIP, the CPU's
private grid copies and the GPU's atomic path.
"""

import numpy as np
import pytest

from tests.physics.test_mpm import box, elastic, make_body, make_scene

STATE = ("x", "v", "C", "H")


def run(scene, bodies_fn, substeps, dt, blocks, mode="auto"):
    from simcli.solvers.mpm import MPMSolver

    solver = MPMSolver(scene, bodies_fn())
    solver.grid_blocks = blocks
    solver.p2g_mode = mode
    solver.build()
    for _ in range(substeps):
        solver.substep(dt)
    st = solver.get_state()
    b = solver.bbox.to_numpy()
    lo, hi = b[:, 0].min(axis=0), b[:, 1].max(axis=0)
    sl = tuple(slice(int(a), int(c)) for a, c in zip(lo, hi))
    gv = solver.grid_v.to_numpy()[sl]  # the updated node velocities over the particles' box
    return solver, st, gv


@pytest.mark.slow  # two 3D builds with a collider's image: a minute of compilation on 2 cores
def test_block_list_matches_the_box_sweep_3d(ti_f32):
    lo1, hi1 = (-0.6, -0.05, 0.05), (-0.5, 0.05, 0.15)
    lo2, hi2 = (0.5, -0.05, 0.25), (0.6, 0.05, 0.35)
    scene = make_scene(
        sim={"dim": 3},
        domain={"lower": [-0.7, -0.1, 0.0], "upper": [0.7, 0.1, 0.4]},
        solvers={"mpm": {"grid_density": 40}},
        entities=[
            {"name": "a", "material": elastic(), "morph": box(lo1, hi1), "velocity": [1.0, 0.0, 0.0]},
            {"name": "b", "material": elastic(), "morph": box(lo2, hi2), "velocity": [-1.0, 0.0, -1.0]},
        ],
        colliders=[{"type": "Sphere", "center": [0.0, 0.0, 0.1], "radius": 0.06, "boundary": "slip"}],
    )

    def bodies():
        return [
            make_body(scene.entities[0], lo1, hi1, 0.0125, fixed_below_x=-0.59),
            make_body(scene.entities[1], lo2, hi2, 0.0125),
        ]

    s_box, a, ga = run(scene, bodies, 60, 5e-4, blocks=False)
    s_blk, b, gb = run(scene, bodies, 60, 5e-4, blocks=True)
    assert s_box.chunked and s_blk.chunked
    for k in STATE:
        assert np.array_equal(a[k], b[k]), k
    assert np.array_equal(ga, gb)  # the box's nodes off the list hold 0 as the sweep wrote
    c_box, c_blk = s_box.counts(), s_blk.counts()
    assert c_blk["box_cells"] == c_box["active_cells"]
    # two bodies 0.4 m apart: the blocks they touch are well under half of the box between them
    assert 0 < c_blk["active_cells"] < 0.5 * c_blk["box_cells"]
    x0 = np.concatenate([body.x for body in bodies()])
    assert np.abs(b["x"] - x0).max() > 0.01  # the bodies moved (not a trivial comparison)


@pytest.mark.parametrize(
    "transfer, mode", [("apic", "chunked"), pytest.param("flip", "atomic", marks=pytest.mark.slow)]
)
def test_block_list_matches_the_box_sweep_2d(ti_f32, transfer, mode):
    lo1, hi1 = (0.1, 0.1), (0.2, 0.2)
    lo2, hi2 = (0.7, 0.6), (0.8, 0.7)
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [1.0, 1.0]},
        solvers={"mpm": {"grid_density": 64, "transfer": transfer}},
        entities=[
            {"name": "a", "material": elastic(), "morph": box(lo1, hi1), "velocity": [2.0, 0.0]},
            {"name": "b", "material": elastic(), "morph": box(lo2, hi2), "velocity": [0.0, -2.0]},
        ],
        colliders=[{"type": "Sphere", "center": [0.36, 0.15], "radius": 0.05, "boundary": "slip"}],
    )

    def bodies():
        return [
            make_body(scene.entities[k], lo, hi, 1 / 128)
            for k, (lo, hi) in enumerate([(lo1, hi1), (lo2, hi2)])
        ]

    s_box, a, ga = run(scene, bodies, 200, 2.5e-4, blocks=False, mode=mode)
    s_blk, b, gb = run(scene, bodies, 200, 2.5e-4, blocks=True, mode=mode)
    assert s_blk.chunked == (mode == "chunked")
    for k in STATE:
        assert np.array_equal(a[k], b[k]), k
    assert np.array_equal(ga, gb)
    assert 0 < s_blk.counts()["active_cells"] < 0.5 * s_blk.counts()["box_cells"]
