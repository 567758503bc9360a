"""Physical invariants of the MPM solver with stated tolerances: free fall, coming to rest on
the floor, colliders, fixed regions, materials, restart, f64, and the GPU-style (atomic) path.

Scenes are built with Scene.model_validate and the bodies directly with numpy (a cell-centred
lattice, mass = rho V / n), so these tests depend on the solver only. Each solver compiles its
kernels once (a few seconds on a 2-core CPU): the tests share module-scoped runs.
"""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

G = 9.81


def lattice(lo, hi, h):
    axes = [np.arange(a + h / 2, b - h / 4, h) for a, b in zip(lo, hi)]
    g = np.meshgrid(*axes, indexing="ij")
    return np.stack([c.ravel() for c in g], axis=1)


def make_body(entity, lo, hi, h, fixed_below_x=None):
    from simcli.solvers.base import Body

    x = lattice(lo, hi, h)
    n = len(x)
    vol = float(np.prod(np.subtract(hi, lo)))
    v = np.zeros_like(x)
    if entity.velocity is not None:
        v[:] = entity.velocity
    fixed = np.zeros(n, bool) if fixed_below_x is None else x[:, 0] < fixed_below_x
    return Body(
        entity.name, entity, x, v, np.full(n, vol / n), np.full(n, entity.material.rho * vol / n), fixed
    )


def make_scene(**kw):
    from simcli.scene.models import Scene

    return Scene.model_validate(kw)


def box(lo, hi):
    return {"type": "Box", "lower": list(lo), "upper": list(hi)}


def elastic(model="corotation", E=3e5, nu=0.2, rho=1000.0):
    return {"type": "MPM.Elastic", "model": model, "E": E, "nu": nu, "rho": rho}


def com(p, m):
    return (p * m[:, None]).sum(axis=0) / m.sum()


# ------------------------------------------------------------------ 3D drop on the floor

DROP_DT, DROP_SUB, DROP_STEPS = 2e-3, 5, 600
DROP_LO, DROP_HI = (-0.05, -0.05, 0.06), (0.05, 0.05, 0.16)


@pytest.fixture(scope="module")
def drop3d(ti_f32):
    """An elastic 0.1 m cube (512 particles) dropped from 6 cm onto the slip floor, 1.2 s."""
    from simcli.solvers.mpm import MPMSolver

    scene = make_scene(
        sim={"dim": 3, "dt": DROP_DT, "substeps": DROP_SUB},
        domain={"lower": [-0.2, -0.2, 0.0], "upper": [0.2, 0.2, 0.4]},
        solvers={"mpm": {"grid_density": 40}},
        entities=[{"name": "cube", "material": elastic(), "morph": box(DROP_LO, DROP_HI)}],
    )
    body = make_body(scene.entities[0], DROP_LO, DROP_HI, 0.0125)
    solver = MPMSolver(scene, [body])
    solver.build()
    stable0 = solver.stable_dt()
    traj = []
    for step in range(DROP_STEPS + 1):
        if step:
            for _ in range(DROP_SUB):
                solver.substep(DROP_DT / DROP_SUB)
        a = solver.entity_arrays("cube", ["position", "velocity"])
        stats = solver.frame_check()["cube"]
        traj.append(
            {
                "t": step * DROP_DT,
                "com": com(a["position"], body.mass),
                "minz": a["position"][:, 2].min(),
                "vmax": np.linalg.norm(a["velocity"], axis=1).max(),
                "finite": stats.finite,
                "stat_speed": stats.max_speed,
            }
        )
    return {"solver": solver, "body": body, "traj": traj, "scene": scene, "stable0": stable0}


def test_free_fall_matches_analytic_before_contact(drop3d):
    z0 = drop3d["traj"][0]["com"][2]
    h = DROP_DT / DROP_SUB
    checked = 0
    # the bottom (z = 0.06 - spacing/2) meets the wall stencil after ~0.09 s; stop at 0.08 s
    for rec in drop3d["traj"]:
        t = rec["t"]
        if t == 0 or t > 0.08:
            continue
        drop = z0 - rec["com"][2]
        # symplectic Euler lags the exact parabola by g t h / 2 (h the substep): 1% from t = 100 h on
        if t >= 100 * h:
            assert drop == pytest.approx(0.5 * G * t * t, rel=0.01), t
            checked += 1
        assert drop == pytest.approx(0.5 * G * (t * t + t * h), rel=2e-3), t  # the discrete solution
        assert abs(rec["com"][0]) < 1e-6 and abs(rec["com"][1]) < 1e-6
    assert checked >= 10


def test_block_comes_to_rest_on_the_floor(drop3d):
    dx = 1 / 40
    traj = drop3d["traj"]
    assert all(r["finite"] for r in traj)
    assert min(r["minz"] for r in traj) >= -0.5 * dx  # never sinks below the floor
    impact = max(r["vmax"] for r in traj)
    assert impact > 0.4  # it did fall (v ~ sqrt(2 g 0.035) at contact)
    late = [r for r in traj if r["t"] >= 1.1]
    assert max(r["vmax"] for r in late) < 0.02 * impact  # the bounces have died out: at rest
    rest_z = np.mean([r["com"][2] for r in late])
    half = 0.05 - 0.0125 / 2
    assert (
        0.0 < rest_z - half < 1.5 * dx
    )  # resting on the floor (grid contact gap below one and a half cells)
    assert all(abs(r["com"][0]) < 1e-4 and abs(r["com"][1]) < 1e-4 for r in traj)  # no sideways drift


def test_frame_check_and_stable_dt(drop3d):
    solver, traj = drop3d["solver"], drop3d["traj"]
    # frame_check's max speed is the largest particle speed
    assert all(r["stat_speed"] == pytest.approx(r["vmax"], rel=1e-5, abs=1e-7) for r in traj)
    # at rest the wave speed decides: 0.5 dx / c_p
    E, nu, rho = 3e5, 0.2, 1000.0
    cp = np.sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu) * rho))
    assert drop3d["stable0"] == pytest.approx(0.5 * (1 / 40) / cp, rel=1e-6)
    assert solver.stable_dt() <= drop3d["stable0"]
    c = solver.counts()
    assert c["particles"] == 512 and c["active_cells"] > 0 and c["grid_cells"] >= c["active_cells"]


def test_restart_reproduces_the_run_bit_for_bit(drop3d):
    solver = drop3d["solver"]
    # give it some motion first
    solver.set_gravity([2.0, 0.0, -G])  # gravity is run-time data: no recompilation
    for _ in range(20):
        solver.substep(4e-4)
    saved = {k: v.copy() for k, v in solver.get_state().items()}
    assert "corotation_q" in saved  # the warm-start rotations are state
    for _ in range(40):
        solver.substep(4e-4)
    first = solver.get_state()
    solver.set_state(saved)
    for _ in range(40):
        solver.substep(4e-4)
    second = solver.get_state()
    for k in first:
        assert np.array_equal(first[k], second[k]), k
    assert not np.array_equal(first["x"], saved["x"])


# ------------------------------------------------------------- 2D: Neo-Hookean on a ramp

RAMP_POINT, RAMP_NORMAL = (0.25, 0.1), (-0.3, 1.0)


def ramp_distance(p):
    n = np.asarray(RAMP_NORMAL) / np.linalg.norm(RAMP_NORMAL)
    return (p - np.asarray(RAMP_POINT)) @ n


@pytest.fixture(scope="module")
def ramp2d(ti_f32):
    from simcli.solvers.mpm import MPMSolver

    lo, hi = (0.2, 0.25), (0.3, 0.35)
    scene = make_scene(
        sim={"dim": 2, "dt": 1e-3, "substeps": 4},
        domain={"lower": [0.0, 0.0], "upper": [0.5, 0.5]},
        colliders=[
            {
                "type": "Plane",
                "point": list(RAMP_POINT),
                "normal": list(RAMP_NORMAL),
                "boundary": "slip",
                "friction": 0.0,
            }
        ],
        solvers={"mpm": {"grid_density": 64}},
        entities=[{"name": "slab", "material": elastic("neohooken", E=2e5, nu=0.3), "morph": box(lo, hi)}],
    )
    body = make_body(scene.entities[0], lo, hi, 1 / 128)
    solver = MPMSolver(scene, [body])
    solver.build()
    traj = []
    for step in range(501):
        if step:
            for _ in range(4):
                solver.substep(2.5e-4)
        p = solver.entity_arrays("slab", ["position"])["position"]
        traj.append(
            {
                "t": step * 1e-3,
                "com": com(p, body.mass),
                "dmin": ramp_distance(p).min(),
                "finite": solver.frame_check()["slab"].finite,
            }
        )
    return {"traj": traj, "body": body, "solver": solver}


def test_2d_free_fall(ramp2d):
    traj = ramp2d["traj"]
    y0 = traj[0]["com"][1]
    for r in traj:
        if 0.04 <= r["t"] <= 0.1:  # lowest corner 0.1 m above the ramp: contact after ~0.14 s
            assert y0 - r["com"][1] == pytest.approx(0.5 * G * r["t"] ** 2, rel=0.01)


def test_2d_slab_respects_the_plane_and_slides_down_it(ramp2d):
    traj = ramp2d["traj"]
    dx = 1 / 64
    assert all(r["finite"] for r in traj)
    assert min(r["dmin"] for r in traj) >= -0.5 * dx  # never through the plane
    # frictionless slip on a slope rising towards +x: it slides towards -x
    assert traj[-1]["com"][0] < traj[0]["com"][0] - 0.02


def test_nan_is_reported_not_a_crash(ramp2d):
    """A blown-up particle (NaN position, inf velocity) must neither crash nor write outside the
    grid: the frame check reports it."""
    solver = ramp2d["solver"]
    state = solver.get_state()
    state["x"][3] = np.nan
    state["v"][5] = np.inf
    solver.set_state(state)
    for _ in range(10):
        solver.substep(2.5e-4)
    st = solver.frame_check()["slab"]
    assert not st.finite and st.n_bad >= 2 and st.max_speed == float("inf")


# --------------------------------------------- colliders, several entities and materials

SPHERE_C, SPHERE_R = (-0.2, 0.0, 0.12), 0.06
BOXC_LO, BOXC_HI = (-0.05, -0.05, 0.0), (0.05, 0.05, 0.12)
CYL_C, CYL_R, CYL_H = (0.2, 0.0, 0.12), 0.03, 0.2


@pytest.fixture(scope="module")
def obstacles(ti_f32):
    """Three cubes dropped on a sphere, a box and a cylinder collider; two material models."""
    from simcli.solvers.mpm import MPMSolver

    soft = elastic("corotation", E=1e5)
    stiff = elastic("neohooken", E=2e5, nu=0.3)
    cubes = {
        "on_sphere": ((-0.24, -0.04, 0.2), (-0.16, 0.04, 0.28), soft),
        "on_box": ((-0.04, -0.04, 0.2), (0.04, 0.04, 0.28), stiff),
        "on_cylinder": ((0.16, -0.04, 0.2), (0.24, 0.04, 0.28), soft),
    }
    scene = make_scene(
        sim={"dim": 3, "dt": 2e-3, "substeps": 5},
        domain={"lower": [-0.35, -0.15, 0.0], "upper": [0.35, 0.15, 0.4]},
        colliders=[
            {"type": "Sphere", "center": list(SPHERE_C), "radius": SPHERE_R, "boundary": "sticky"},
            {
                "type": "Box",
                "lower": list(BOXC_LO),
                "upper": list(BOXC_HI),
                "boundary": "separate",
                "friction": 0.5,
            },
            {
                "type": "Cylinder",
                "center": list(CYL_C),
                "radius": CYL_R,
                "height": CYL_H,
                "axis": "y",
                "boundary": "slip",
            },
        ],
        solvers={"mpm": {"grid_density": 50}},
        entities=[{"name": k, "material": m, "morph": box(lo, hi)} for k, (lo, hi, m) in cubes.items()],
    )
    bodies = [make_body(e, cubes[e.name][0], cubes[e.name][1], 0.01) for e in scene.entities]
    solver = MPMSolver(scene, bodies)
    solver.build()
    initial = {b.name: solver.entity_arrays(b.name, ["J", "stress"]) for b in bodies}
    worst = {b.name: np.inf for b in bodies}
    for step in range(250):
        for _ in range(5):
            solver.substep(4e-4)
        if step % 5 == 4:
            for b in bodies:
                p = solver.entity_arrays(b.name, ["position"])["position"]
                worst[b.name] = min(worst[b.name], _collider_distance(b.name, p).min())
    final = {
        b.name: solver.entity_arrays(b.name, ["position", "velocity", "J", "stress", "material_id"])
        for b in bodies
    }
    return {
        "solver": solver,
        "bodies": bodies,
        "initial": initial,
        "final": final,
        "worst": worst,
        "stats": solver.frame_check(),
    }


def _collider_distance(name, p):
    if name == "on_sphere":
        return np.linalg.norm(p - np.asarray(SPHERE_C), axis=1) - SPHERE_R
    if name == "on_box":
        c = (np.asarray(BOXC_LO) + np.asarray(BOXC_HI)) / 2
        h = (np.asarray(BOXC_HI) - np.asarray(BOXC_LO)) / 2
        q = np.abs(p - c) - h
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    d = p - np.asarray(CYL_C)
    radial = np.linalg.norm(d[:, [0, 2]], axis=1) - CYL_R
    axial = np.abs(d[:, 1]) - CYL_H / 2
    return np.where((radial > 0) & (axial > 0), np.hypot(radial, axial), np.maximum(radial, axial))


def test_colliders_are_respected(obstacles):
    dx = 1 / 50
    for name, d in obstacles["worst"].items():
        assert d >= -0.5 * dx, name
    for name, arr in obstacles["final"].items():
        # each cube came to lie on its obstacle: above its top, well above the floor
        assert arr["position"][:, 2].min() > 0.1, name


def test_entities_materials_and_output_fields(obstacles):
    stats, final, initial = obstacles["stats"], obstacles["final"], obstacles["initial"]
    assert set(stats) == {"on_sphere", "on_box", "on_cylinder"}
    assert all(s.finite and s.n_bad == 0 for s in stats.values())
    for b in obstacles["bodies"]:
        arr = final[b.name]
        assert arr["position"].shape == (b.n, 3) and arr["velocity"].shape == (b.n, 3)
        assert arr["J"].shape == (b.n,) and arr["stress"].shape == (b.n,)
        assert np.all(initial[b.name]["J"] == 1.0) and np.all(initial[b.name]["stress"] == 0.0)
        # resting on an obstacle under gravity: compressed a little, stressed (von Mises, Pa)
        assert 0.9 < arr["J"].min() and arr["J"].max() < 1.05
        assert 10.0 < np.median(arr["stress"]) < 1e4
    # one id per distinct material: the two soft cubes share theirs
    mids = {k: set(v["material_id"].tolist()) for k, v in final.items()}
    assert mids["on_sphere"] == mids["on_cylinder"] and len(mids["on_sphere"]) == 1
    assert mids["on_box"] != mids["on_sphere"]


def test_sticky_sphere_holds_its_cube(obstacles):
    # sticky: the nodes inside the sphere do not move, so the cube stays perched near its top
    p = obstacles["final"]["on_sphere"]["position"]
    assert abs(com(p, np.ones(len(p)))[0] - SPHERE_C[0]) < 0.02


# ---------------------------------------------------------- 2D Coulomb friction on the floor


def test_sliding_block_decelerates_at_mu_g(ti_f32):
    """A block sliding on a floor with Coulomb friction mu: v(t) = v0 - mu g t, stop at v0^2 / (2 mu g)."""
    from simcli.solvers.mpm import MPMSolver

    mu, v0, dx, h = 0.3, 1.0, 1 / 64, 2.5e-4
    lo, hi = (0.1, 1.2 * dx), (0.2, 1.2 * dx + 0.05)  # about where the grid contact lets it rest
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [1.0, 0.5], "faces": {"y-": {"type": "slip", "friction": mu}}},
        solvers={"mpm": {"grid_density": 64}},
        entities=[{"name": "b", "material": elastic(), "morph": box(lo, hi)}],
    )
    body = make_body(scene.entities[0], lo, hi, dx / 2)
    solver = MPMSolver(scene, [body])
    solver.build()
    for _ in range(800):  # settle for 0.2 s
        solver.substep(h)
    state = solver.get_state()
    state["v"][:, 0] += v0
    solver.set_state(state)
    x0 = solver.entity_arrays("b", ["position"])["position"][:, 0].mean()
    for k in range(1, 2001):
        solver.substep(h)
        if k % 400 == 0 and k * h < 0.3:
            v = solver.entity_arrays("b", ["velocity"])["velocity"][:, 0].mean()
            assert v == pytest.approx(v0 - mu * G * k * h, abs=0.03), k * h
    a = solver.entity_arrays("b", ["position", "velocity"])
    assert abs(a["velocity"][:, 0].mean()) < 0.05  # stopped
    assert a["position"][:, 0].mean() - x0 == pytest.approx(v0**2 / (2 * mu * G), rel=0.05)


# ------------------------------------------------------------------ 2D fixed cantilever


def test_fixed_region_clamps_a_cantilever(ti_f32):
    from simcli.solvers.mpm import MPMSolver

    lo, hi = (0.05, 0.3), (0.35, 0.34)
    scene = make_scene(
        sim={"dim": 2, "dt": 1e-3, "substeps": 4},
        domain={"lower": [0.0, 0.0], "upper": [0.5, 0.5]},
        solvers={"mpm": {"grid_density": 100}},
        entities=[
            {
                "name": "beam",
                "material": elastic(E=1e6, nu=0.3),
                "morph": box(lo, hi),
                "fixed": box((0.0, 0.0), (0.1, 0.5)),
            }
        ],
    )
    body = make_body(scene.entities[0], lo, hi, 0.005, fixed_below_x=0.1)
    assert body.fixed.sum() > 0
    solver = MPMSolver(scene, [body])
    solver.build()
    x0 = body.x.astype(np.float32)
    for _ in range(1200):  # 0.3 s
        solver.substep(2.5e-4)
    x = solver.entity_arrays("beam", ["position"])["position"]
    assert np.array_equal(x[body.fixed], x0[body.fixed])  # held exactly
    near = (~body.fixed) & (body.x[:, 0] < 0.11)
    assert np.abs(x[near] - x0[near]).max() < 0.5 / 100  # the clamp holds the adjacent material
    tip = body.x[:, 0] > 0.34
    sag = x0[tip, 1].mean() - x[tip, 1].mean()
    assert 0.0 < sag < 0.08  # it bends under gravity but does not fall off
    assert solver.frame_check()["beam"].finite


# ------------------------------------------------------- the GPU code path, run on the CPU


def test_atomic_p2g_path_matches_the_chunked_path(ti_f32):
    """GPUs use one grid and atomic adds; check that path against the CPU's private copies."""
    from simcli.solvers.mpm import MPMSolver

    lo, hi = (0.4, 0.3), (0.6, 0.5)
    scene = make_scene(
        sim={"dim": 2},
        domain={"lower": [0.0, 0.0], "upper": [1.0, 1.0]},
        solvers={"mpm": {"grid_density": 64}},
        entities=[{"name": "b", "material": elastic(), "morph": box(lo, hi), "velocity": [0.5, 0.0]}],
    )
    runs = {}
    for mode in ("chunked", "atomic"):
        body = make_body(scene.entities[0], lo, hi, 1 / 128)
        solver = MPMSolver(scene, [body])
        solver.p2g_mode = mode
        solver.build()
        assert solver.chunked == (mode == "chunked")
        for _ in range(800):
            solver.substep(2.5e-4)
        runs[mode] = solver.entity_arrays("b", ["position"])["position"]
    assert np.abs(runs["chunked"] - runs["atomic"]).max() < 1e-4


# ------------------------------------------------------------------------------ f64

F64_SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    sys.path.insert(0, {tests!r})
    from simcli.backend import init_taichi
    init_taichi("cpu", "f64")
    from physics.test_mpm import make_scene, make_body, box, elastic
    from simcli.solvers.mpm import MPMSolver
    lo, hi = (0.4, 0.6), (0.6, 0.7)
    scene = make_scene(sim={{"dim": 2, "precision": "f64"}}, domain={{"lower": [0, 0], "upper": [1, 1]}},
                       solvers={{"mpm": {{"grid_density": 64}}}},
                       entities=[{{"name": "b", "material": elastic(), "morph": box(lo, hi)}}])
    body = make_body(scene.entities[0], lo, hi, 1 / 128)
    s = MPMSolver(scene, [body]); s.build()
    y0 = s.entity_arrays("b", ["position"])["position"][:, 1].mean()
    for _ in range(400):
        s.substep(2.5e-4)
    p = s.entity_arrays("b", ["position"])["position"]
    saved = {{k: v.copy() for k, v in s.get_state().items()}}
    for _ in range(50):
        s.substep(2.5e-4)
    a = s.get_state()["x"]
    s.set_state(saved)
    for _ in range(50):
        s.substep(2.5e-4)
    print(json.dumps({{"dtype": str(p.dtype), "drop": float(y0 - p[:, 1].mean()),
                      "restart_equal": bool(np.array_equal(a, s.get_state()["x"]))}}))
""")


def test_f64_run_in_a_subprocess():
    tests = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    repo = os.path.dirname(tests)
    env = dict(os.environ, PYTHONPATH=repo + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run(
        [sys.executable, "-c", F64_SCRIPT.format(tests=tests)],
        capture_output=True,
        text=True,
        check=False,
        env=env,
        timeout=300,
        cwd=repo,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["dtype"] == "float64"
    t = 400 * 2.5e-4
    # symplectic Euler: the discrete drop is g t^2 / 2 + g t dt / 2
    assert res["drop"] == pytest.approx(0.5 * G * t * t + 0.5 * G * t * 2.5e-4, rel=1e-6)
    assert res["restart_equal"]
