"""PBD against references (shared/reference/README.md and issue #7).

* free fall: a cloth with no contact falls as z0 - g t^2 / 2 (symplectic Euler's g dt t / 2 offset
  allowed) and keeps its edge lengths;
* hanging chain of 20 unit masses: the support force is 19 m g (f64, in a subprocess);
* stiffness independence (slow): a cloth strip's sag changes by less than 3 % between 20 and 160
  stretch iterations and between dt and dt / 2.
The spring period, catenary and drape cases are validation cases (configs/validation/pbd_*).
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_free_fall_of_a_cloth(ti_f32):
    from simcli.scene.models import Scene
    from simcli.solvers.pbd.solver import PBDSolver

    dt, n = 1e-3, 200
    scene = Scene.model_validate(
        {
            "sim": {"dt": dt, "substeps": 1},
            "domain": {"lower": [-1, -1, 0], "upper": [1, 1, 2]},
            "entities": [
                {
                    "name": "c",
                    "material": {"type": "PBD.Cloth", "rho": 0.3},
                    "morph": {
                        "type": "Rectangle",
                        "center": [0, 0, 1.5],
                        "size": [0.4, 0.3],
                        "resolution": 8,
                    },
                }
            ],
        }
    )
    s = PBDSolver(scene, [])
    s.build()
    for _ in range(n):
        s.substep(dt)
    x = s.x.to_numpy().astype(np.float64)
    t = n * dt
    exact = 1.5 - 0.5 * 9.81 * t * t
    assert x[:, 2].mean() == pytest.approx(exact, abs=0.5 * 9.81 * dt * t + 1e-5)
    e = s.stretch.idx
    assert np.allclose(np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1), s.stretch.rest, atol=1e-5)
    v = s.v.to_numpy()
    assert np.allclose(v[:, 2], -9.81 * t, rtol=1e-4) and np.abs(v[:, :2]).max() < 1e-5


CHAIN = r"""
import json, sys
from simcli.backend import init_taichi
init_taichi("cpu", "f64")
from simcli.scene.loader import load_scene
from simcli.solvers.pbd.solver import PBDSolver
out = {}
for it in (5, 50):
    sc = load_scene(sys.argv[1], [f"solvers.pbd.stretch_iterations={it}", "sim.precision=f64"]).scene
    s = PBDSolver(sc, []); s.build()
    dt = sc.sim.dt / sc.sim.substeps
    for _ in range(1000):
        s.substep(dt)
    out[it] = float(s.entity_arrays("chain", ["reaction"])["reaction"][:, 2].sum())
print(json.dumps(out))
"""


def test_hanging_chain_support_force_is_19_m_g():
    r = subprocess.run(
        [sys.executable, "-c", CHAIN, str(ROOT / "configs/validation/pbd_chain.yaml")],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    force = json.loads(r.stdout.strip().splitlines()[-1])
    for it, fz in force.items():
        assert fz == pytest.approx(19 * 9.81, rel=1e-3), it


SAG = r"""
import json, sys
import numpy as np
from simcli.backend import init_taichi
init_taichi("cpu", "f64")
from simcli.scene.loader import load_scene
from simcli.solvers.pbd.solver import PBDSolver
out = {}
for name, sets in (("it20", ["solvers.pbd.stretch_iterations=20"]),
                   ("it160", ["solvers.pbd.stretch_iterations=160"]),
                   ("half_dt", ["solvers.pbd.stretch_iterations=20", "sim.substeps=20"])):
    sc = load_scene(sys.argv[1], sets).scene
    s = PBDSolver(sc, []); s.build()
    dt = sc.sim.dt / sc.sim.substeps
    steps = int(round(sc.sim.duration / dt))
    z0 = s.x.to_numpy()[:, 2].max()
    sag = []
    for k in range(steps):
        s.substep(dt)
        if k * dt >= 2.0 and k % 10 == 0:
            sag.append(z0 - s.x.to_numpy()[:, 2].min())
    out[name] = float(np.mean(sag))
print(json.dumps(out))
"""


@pytest.mark.slow
def test_cloth_sag_does_not_depend_on_iterations_or_substep():
    r = subprocess.run(
        [sys.executable, "-c", SAG, str(ROOT / "configs/validation/pbd_cloth_sag.yaml")],
        capture_output=True,
        text=True,
        timeout=1200,
        check=False,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    sag = json.loads(r.stdout.strip().splitlines()[-1])
    assert sag["it20"] > 0.02  # the strip does sag (it is exactly as long as the span)
    assert abs(sag["it160"] / sag["it20"] - 1) < 0.03
    assert abs(sag["half_dt"] / sag["it20"] - 1) < 0.03


def test_fixed_vertices_on_a_prescribed_path(ti_f32):
    """`fixed_velocity`: the held edge of a cloth moves on x0 + v t; with no gravity the sheet follows it
    rigidly (edges keep their length) and the free vertices end with the same velocity."""
    from simcli.scene.models import Scene
    from simcli.solvers.pbd.solver import PBDSolver

    dt, n = 1e-3, 300
    scene = Scene.model_validate(
        {
            "sim": {"dt": dt, "substeps": 1, "gravity": [0, 0, 0]},
            "domain": {"lower": [-1, -1, 0], "upper": [1, 1, 2]},
            "solvers": {"pbd": {"stretch_iterations": 20}},
            "entities": [
                {
                    "name": "c",
                    "material": {"type": "PBD.Cloth", "rho": 0.3, "fixed_velocity": [0.5, 0, 0]},
                    "morph": {
                        "type": "Rectangle",
                        "center": [0, 0, 1.0],
                        "size": [0.4, 0.2],
                        "resolution": 8,
                    },
                    "fixed": {"type": "Box", "lower": [-0.21, -0.2, 0.9], "upper": [-0.19, 0.2, 1.1]},
                }
            ],
        }
    )
    s = PBDSolver(scene, [])
    s.build()
    for _ in range(n):
        s.substep(dt)
    x = s.x.to_numpy().astype(np.float64)
    held = s.fixed
    assert held.sum() == 9
    assert np.allclose(x[held], s.x0[held] + [0.5 * n * dt, 0, 0], atol=1e-5)
    e = s.stretch.idx
    assert np.allclose(np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1), s.stretch.rest, atol=1e-4)
    v = s.v.to_numpy()
    assert np.allclose(v[:, 0], 0.5, atol=0.02)


def test_liquid_block_at_rest_keeps_density_mass_and_height(ti_f32):
    """PBD.Liquid (position-based fluids): a block of liquid released on the floor of a box that fits it.
    The initial lattice is at the rest density (rho0 is its kernel sum; the walls' mirrored lattice
    completes the particles next to them, 0.3 % short at the 8 corners), the mass is rho x volume, the
    compression stays below 1 % and the block keeps its height (without the walls' density it sank by a
    particle layer, packing against the walls)."""
    from simcli.scene.models import Scene
    from simcli.solvers.pbd.solver import PBDSolver

    ps = 0.01
    scene = Scene.model_validate(
        {
            "sim": {"dt": 2e-3, "substeps": 5},
            "domain": {"lower": [0, 0, 0], "upper": [0.08, 0.08, 0.3]},
            "solvers": {"pbd": {"particle_size": ps}},
            "entities": [
                {
                    "name": "w",
                    "material": {"type": "PBD.Liquid", "rho": 1000},
                    "morph": {"type": "Box", "lower": [0, 0, 0], "upper": [0.08, 0.08, 0.08]},
                }
            ],
        }
    )
    s = PBDSolver(scene, [])
    s.build()
    assert s.counts()["particles"] == 512
    assert s.mass.sum() == pytest.approx(1000 * 0.08**3)
    rho0 = s.liquids[0].rho0
    s.substep(4e-4)
    rho = s.entity_arrays("w", ["density"])["density"] / rho0
    below_top = s.x.to_numpy()[:, 2] < 0.07
    assert rho[below_top].min() > 0.996 and rho[below_top].max() < 1.001
    worst = 0.0
    for k in range(500):  # 0.2 s
        s.substep(4e-4)
        if k % 50 == 49:
            worst = max(worst, float(s.entity_arrays("w", ["density"])["density"].max()))
    assert worst < 1.01 * rho0
    x = s.x.to_numpy()
    assert abs(x[:, 2].max() - 0.075) < 0.5 * ps  # the top layer stays where it was
    assert np.abs(s.v.to_numpy()).max() < 0.3
    assert x[:, 2].min() >= 0.5 * ps - 1e-6 and x[:, :2].max() <= 0.08 - 0.5 * ps + 1e-6


def test_state_round_trip_restarts_bit_for_bit(ti_f32):
    """get_state / set_state (checkpoints): a second solver started from the first's state continues
    identically (multipliers are reset every substep, neighbour lists rebuilt, so x, v and time suffice)."""
    from simcli.scene.models import Scene
    from simcli.solvers.pbd.solver import PBDSolver

    scene = Scene.model_validate(
        {
            "sim": {"dt": 2e-3, "substeps": 4},
            "domain": {"lower": [-0.5, -0.5, 0], "upper": [0.5, 0.5, 1]},
            "colliders": [{"type": "Sphere", "center": [0, 0, 0.3], "radius": 0.1, "friction": 0.3}],
            "entities": [
                {
                    "name": "c",
                    "material": {"type": "PBD.Cloth", "rho": 0.3},
                    "morph": {
                        "type": "Rectangle",
                        "center": [0, 0, 0.45],
                        "size": [0.4, 0.4],
                        "resolution": 10,
                    },
                }
            ],
        }
    )
    a, b = PBDSolver(scene, []), PBDSolver(scene, [])
    a.build()
    b.build()
    for _ in range(40):
        a.substep(5e-4)
    b.set_state(a.get_state())
    for _ in range(40):
        a.substep(5e-4)
        b.substep(5e-4)
    assert np.array_equal(a.x.to_numpy(), b.x.to_numpy()) and np.array_equal(a.v.to_numpy(), b.v.to_numpy())
    assert a.time == b.time
