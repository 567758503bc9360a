"""Colliders in prescribed motion and the loads on named colliders (issue 19), MPM in process.

The weight of a resting block read on the named collider under it; a paddle turning at 2 rev/s through
a block of sand keeps every particle within half a cell of its surface; a collider translating into a
block pushes it along without letting it in (grid nodes take the collider's velocity)."""

import math

import numpy as np
import pytest

from tests.physics.test_mpm import G, box, elastic, make_body, make_scene


def _solver(scene, lo, hi, h):
    from simcli.solvers.mpm import MPMSolver

    s = MPMSolver(scene, [make_body(scene.entities[0], lo, hi, h)])
    s.build()
    return s


def test_resting_block_weight_is_read_on_the_named_collider(ti_f32):
    lo, hi = (0.4, 0.1), (0.6, 0.2)
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [1.0, 0.5]},
        colliders=[{"name": "table", "type": "Box", "lower": [0.2, 0.0], "upper": [0.8, 0.1]}],
        solvers={"mpm": {"grid_density": 64}},
        entities=[{"name": "b", "material": elastic("neohooken", E=2e5, nu=0.3), "morph": box(lo, hi)}],
    )
    s = _solver(scene, lo, hi, 0.0078)
    dt, n_settle, n_avg = 2e-4, 1000, 4000
    for _ in range(n_settle):
        s.substep(dt)
    s.collider_loads()  # discard the landing
    for _ in range(n_avg):
        s.substep(dt)
    load = s.collider_loads()["table"]
    force = load[:2] / (n_avg * dt)
    weight = 1000.0 * 0.02 * G
    assert force[1] == pytest.approx(-weight, rel=0.03)
    assert abs(force[0]) < 0.01 * weight
    # torque about the table's centre (0.5, 0.05): the weight's moment, at the block's centre of mass
    xc = s.entity_arrays("b", ["position"])["position"][:, 0].mean()
    assert load[2 + 2] / (n_avg * dt) == pytest.approx(-(xc - 0.5) * weight, abs=0.003 * weight * 0.1)


def test_paddle_turning_through_sand_lets_no_particle_in(ti_f32):
    from simcli.motion import collider_motion
    from simcli.solvers.sph.boundary import sdf_numpy

    lo, hi = (0.0, 0.0), (0.6, 0.2)
    paddle = {
        "name": "paddle",
        "type": "Box",
        "lower": [0.22, 0.085],
        "upper": [0.38, 0.1],
        "motion": {"angular_velocity": [4 * math.pi]},
    }
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [0.6, 0.4]},
        colliders=[paddle],
        solvers={"mpm": {"grid_density": 64}},
        entities=[
            {
                "name": "sand",
                "material": {"type": "MPM.Sand", "E": 1e6, "nu": 0.3, "rho": 1600, "friction_angle": 30},
                "morph": box(lo, hi),
            }
        ],
    )
    s = _solver(scene, lo, hi, 0.0078)
    motion = collider_motion(scene.colliders[0], 2)
    spec = s.boundary.colliders[0]
    dx, dt = 1.0 / 64, 2e-4
    deepest, torques = 0.0, []
    for k in range(1, 1251):  # a quarter of a second: half a turn
        s.substep(dt)
        if k % 50 == 0:
            x = s.entity_arrays("sand", ["position"])["position"].astype(np.float64)
            phi = sdf_numpy(spec, motion.pose(k * dt).to_body(x))
            deepest = max(deepest, float(-phi.min()))
            torques.append(s.collider_loads()["paddle"][2 + 2])
    assert deepest < 0.5 * dx
    assert np.mean(torques) < 0  # the sand resists the paddle's (positive) turning


def test_translating_collider_pushes_a_block_and_lets_none_of_it_in(ti_f32):
    lo, hi = (0.3, 0.02), (0.4, 0.07)
    scene = make_scene(
        sim={"dim": 2, "gravity": [0.0, 0.0]},
        domain={"lower": [0.0, 0.0], "upper": [1.0, 0.3]},
        colliders=[
            {
                "type": "Box",
                "lower": [0.2, 0.0],
                "upper": [0.28, 0.1],
                "boundary": "sticky",
                "motion": {"linear_velocity": [0.5, 0.0]},
            }
        ],
        solvers={"mpm": {"grid_density": 128}},
        entities=[{"name": "b", "material": elastic("neohooken", E=1e5, nu=0.3), "morph": box(lo, hi)}],
    )
    s = _solver(scene, lo, hi, 0.0039)
    for _ in range(2000):  # 0.2 s: the pusher meets the block after about 0.04 s
        s.substep(1e-4)
    a = s.entity_arrays("b", ["position", "velocity"])
    # pushed along: at least the pusher's speed (an elastic block may rebound ahead of it, up to 2 v)
    assert 0.45 < a["velocity"][:, 0].mean() < 1.05
    # the pusher's face is at 0.28 + 0.5 * 0.2 = 0.38: no particle behind it
    assert a["position"][:, 0].min() > 0.38 - 0.5 / 128


PUSH = """\
version: 1
sim: {{dim: 3, dt: {dt}, substeps: {sub}, duration: 0.8}}
domain: {{lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 1.0]}}
colliders:
  - {{name: table, type: Box, lower: [-0.4, -0.3, 0.0], upper: [0.4, 0.3, 0.1], friction: 0.5}}
  - {{name: pusher, type: Box, lower: [-0.25, -0.15, 0.105], upper: [-0.2, 0.15, 0.3],
     motion: {{linear_velocity: [0.3, 0, 0]}}}}
solvers: {solvers}
entities:
  - name: block
    material: {material}
    morph: {{type: Box, center: [0.0, 0, 0.2151], size: [0.2, 0.2, 0.2]}}
output: {{every: 5, formats: [hdf5]}}
"""

PBD = dict(
    dt="4.0e-3",
    sub=10,
    solvers="{pbd: {tet_resolution: 8, stretch_iterations: 10}}",
    material="{type: PBD.Elastic, rho: 1000, stretch_compliance: 1.0e-5, volume_compliance: 0.0}",
)
FEM = dict(
    dt="2.0e-3",
    sub="auto",
    solvers="{{fem: {{integrator: {}, resolution: 8}}}}",
    material="{type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000, model: stable_neohookean}",
)


@pytest.mark.parametrize(
    "family",
    ["pbd", "fem_explicit", pytest.param("fem_implicit", marks=pytest.mark.slow)],  # (suite time)
)
def test_box_pushed_along_a_frictional_table_by_a_moving_collider(tmp_path, family):
    """A Box collider moving at 0.3 m/s pushes an elastic block (8 kg) along a named table with friction
    0.5: once sliding, the pusher reads the Coulomb force mu m g and the table the same the other way and
    the weight; the block stays ahead of the pusher's face."""
    import subprocess
    import sys

    import h5py

    kw = dict(PBD) if family == "pbd" else dict(FEM, solvers=FEM["solvers"].format(family.split("_")[1]))
    scene = tmp_path / "push.yaml"
    scene.write_text(PUSH.format(**kw))
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(tmp_path / "out"), "-q"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stderr
    with h5py.File(tmp_path / "out" / "sim.h5", "r") as f:
        t = f["time"][...]
        push, table = f["colliders/pusher/force"][...], f["colliders/table/force"][...]
        x = f["entities/block/position"][...]
    s = t >= 0.5
    mg = 1000 * 0.008 * G
    assert push[s, 0].mean() == pytest.approx(-0.5 * mg, rel=0.1)
    assert table[s, 0].mean() == pytest.approx(0.5 * mg, rel=0.1)
    assert table[s, 2].mean() == pytest.approx(-mg, rel=0.05)
    # the pusher covers z > 0.105: the block's vertices above it stay ahead of its face
    face = -0.2 + 0.3 * t
    above = x[:, :, 2] > 0.11
    xmin = np.where(above, x[:, :, 0], np.inf).min(axis=1)
    assert np.all(xmin[s] > face[s] - 0.003)
