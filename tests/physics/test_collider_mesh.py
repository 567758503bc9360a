"""`type: Mesh` colliders and collider restitution (issue 19), in process.

A PBD particle dropped on a Mesh slab (restitution 0.5) and one on a Box (restitution 0.8) rebound to e^2
of their drop height; a star-shaped Mesh paddle turning at 2 rev/s through MPM sand keeps every particle
within half a cell of its exact surface; the signed-distance grid matches the exact distance."""

import math
from pathlib import Path

import numpy as np
import pytest

from tests.physics.test_mpm import box, make_body, make_scene

ROOT = Path(__file__).resolve().parents[2]
MESHES = ROOT / "configs" / "meshes"


def _first_rebound(z: np.ndarray) -> tuple[float, float]:
    """(drop height, rebound height) of a height history, above the lowest point of the first bounce."""
    i = int(np.argmax(np.diff(z) > 0))  # first step going up: the bounce
    return float(z[0] - z[i]), float(z[i:].max() - z[i])


def test_pbd_particles_rebound_to_e_squared_of_their_drop_height(ti_f32):
    """Three particles dropped 0.225 m onto three slabs: a Mesh cube with restitution 0.5, a Box with 0.8
    and a Mesh cube without: they rebound to e^2 of the drop, and the last stays on its slab."""
    from simcli.solvers.pbd.solver import PBDSolver

    slab = {"type": "Mesh", "file": "cube.obj", "scale": [0.08, 0.1, 0.05]}
    scene = make_scene(
        sim={"dt": 2e-3, "substeps": 1},
        domain={"lower": [-0.2, -0.1, 0.0], "upper": [0.2, 0.1, 0.4]},
        colliders=[
            dict(slab, translate=[-0.12, 0.0, 0.05], restitution=0.5),
            {"type": "Box", "lower": [-0.04, -0.05, 0.025], "upper": [0.04, 0.05, 0.075], "restitution": 0.8},
            dict(slab, translate=[0.12, 0.0, 0.05]),
        ],
        solvers={"pbd": {"particle_size": 0.01}},
        entities=[
            {
                "name": f"p{k}",
                "material": {"type": "PBD.Particle", "rho": 1000},
                "morph": box((x - 0.005, -0.005, 0.3), (x + 0.005, 0.005, 0.31)),
            }
            for k, x in enumerate((-0.12, 0.0, 0.12))
        ],
    )
    s = PBDSolver(scene, [], scene_dir=MESHES)
    s.build()
    zs = [s.x.to_numpy()[:, 2].astype(np.float64)]
    for _ in range(1200):  # 0.6 s: the drop (0.21 s) and the rebound
        s.substep(5e-4)
        zs.append(s.x.to_numpy()[:, 2].astype(np.float64))
    zs = np.array(zs)
    for k, e in enumerate((0.5, 0.8)):
        h0, h1 = _first_rebound(zs[:, k])
        assert h0 == pytest.approx(0.225, abs=0.002)  # it lands on the slab's top (0.075) + its radius
        assert h1 / h0 == pytest.approx(e * e, abs=0.02)
    # no restitution: it rests on the slab's top at its radius, within the grid's error, and never rises
    assert zs[-1, 2] == pytest.approx(0.08, abs=2e-4)
    assert zs[500:, 2].max() < 0.0802


@pytest.mark.slow  # an MPM compile; `simcli verify mpm_mesh_paddle_sand` runs the same case for 0.5 s
def test_star_mesh_paddle_turning_through_sand_lets_no_particle_in(ti_f32):
    """A star-shaped (sharp-tipped) Mesh paddle turning at 2 rev/s in MPM sand: the deepest particle,
    by the exact distance to the triangles, stays below half a cell; the sand resists the turning."""
    from simcli.collider_mesh import exact_depth
    from simcli.motion import collider_motion
    from simcli.solvers.mpm import MPMSolver

    lo, hi = (0.0, 0.0, 0.0), (0.4, 0.4, 0.1)
    paddle = {
        "name": "paddle",
        "type": "Mesh",
        "file": "star_paddle.obj",
        "scale": [0.12, 0.12, 0.08],
        "translate": [0.2, 0.2, 0.08],
        "motion": {"angular_velocity": [0, 0, 4 * math.pi]},
    }
    scene = make_scene(
        domain={"lower": [0.0, 0.0, 0.0], "upper": [0.4, 0.4, 0.2]},
        colliders=[paddle],
        solvers={"mpm": {"grid_density": 32}},
        entities=[
            {
                "name": "sand",
                "material": {"type": "MPM.Sand", "E": 1e6, "nu": 0.3, "rho": 1600, "friction_angle": 30},
                "morph": box(lo, hi),
            }
        ],
    )
    s = MPMSolver(scene, [make_body(scene.entities[0], lo, hi, 0.02)], scene_dir=MESHES)
    s.build()
    c = scene.colliders[0]
    motion = collider_motion(c, 3)
    dx, dt = 1.0 / 32, 5e-4
    deepest, torques = 0.0, []
    for k in range(1, 121):  # 0.06 s: an eighth of a turn
        s.substep(dt)
        if k % 40 == 0:
            x = s.entity_arrays("sand", ["position"])["position"].astype(np.float64)
            deepest = max(deepest, exact_depth(c, motion.pose(k * dt).to_body(x), scene, MESHES))
            torques.append(s.collider_loads()["paddle"][3 + 2])
    assert deepest < 0.5 * dx
    assert np.mean(torques) < 0  # the sand resists the paddle's (positive) turning


def test_mesh_sdf_grid_matches_the_exact_signed_distance():
    from simcli.collider_mesh import build_sdf, mesh_distance
    from simcli.geometry.mesh import TriMesh, points_inside_mesh

    c = make_scene(
        entities=[],
        colliders=[{"type": "Mesh", "file": "star_paddle.obj", "scale": 0.1, "sdf_cell": 0.004}],
    ).colliders[0]
    sdf = build_sdf(c, None, MESHES)
    rng = np.random.default_rng(1)
    lo, hi = sdf.bounds
    x = rng.uniform(lo - 0.01, hi + 0.01, (3000, 3))
    mesh = TriMesh(sdf.vertices, sdf.triangles, sdf.volume)
    exact = mesh_distance(sdf.vertices, sdf.triangles, x) * np.where(points_inside_mesh(mesh, x), -1, 1)
    near = np.abs(exact) < 2 * sdf.h
    err = np.abs(sdf.sample(x) - exact)[near]
    assert near.sum() > 200
    assert np.percentile(err, 99) < 0.5 * sdf.h
    assert err.max() < sdf.h
    # far inside: still negative (a usable push-out direction), never positive
    assert np.all(sdf.sample(x)[exact < -2 * sdf.h] < 0)
