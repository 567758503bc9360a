"""PBD in 2D scenes (sim.dim: 2): PBD.Liquid (position-based fluids) and PBD.Particle from the same kernels as
3D, with the 2D kernels' normalisation, masses per metre of depth, walls, colliders and free rigid bodies.

* the 2D poly6 and spiky kernels are normalised over the disk, and an interior particle of the square
  rest lattice sums to the rest density;
* a 2D liquid column at rest keeps its density (within 1 %), its mass (rho x area) and its height;
* PBD.Particle grains fall onto a circle collider and the floor and come to rest inside the domain;
* a rigid box (rho 500) dropped on 2D PBF water floats: the liquid carries its weight;
* a sink drains a 2D pool and an emitter refills it: the mass in the scene is the start's plus what
  entered minus what left;
* what stays 3D only (PBD.Cloth, PBD.Elastic, coupling with other families, Cylinder morphs) is refused
  by ``validate`` with exit 65 and its file:line:col.
"""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(args, timeout=600):
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT
    )


def test_2d_kernels_are_normalised_and_the_rest_lattice_sums_to_rho0():
    from simcli.solvers.pbd.liquid import lattice_constants, poly6, spiky_grad_mag

    h = 0.02
    r = np.linspace(0.0, h, 20001)
    # int_0^h W(r) 2 pi r dr = 1 (2D) and 4 pi r^2 dr (3D)
    assert np.trapezoid(poly6(r, h, 2) * 2 * math.pi * r, r) == pytest.approx(1.0, rel=1e-6)
    assert np.trapezoid(poly6(r, h, 3) * 4 * math.pi * r * r, r) == pytest.approx(1.0, rel=1e-6)
    # the spiky kernel's slope integrates back to W(0) - W(h) = 10 / (pi h^2) in 2D
    assert -np.trapezoid(spiky_grad_mag(r, h, 2), r) == pytest.approx(10.0 / (math.pi * h**2), rel=1e-4)
    # the square lattice at h = 2 spacing: sum W x spacing^2 close to 1 (the kernel's discrete integral)
    wsum, gsum = lattice_constants(0.01, h, 2)
    assert wsum * 0.01**2 == pytest.approx(1.0, abs=0.05)
    assert gsum > 0


def test_2d_liquid_column_at_rest_keeps_density_mass_and_height(ti_f32):
    """A 2D block of PBD.Liquid on the floor of a box that fits it: mass rho x area (per metre of depth),
    the initial lattice at the rest density (the walls' mirrored lattice completes the particles next to
    them), compression below 1 % and the top layer where it was."""
    from simcli.scene.models import Scene
    from simcli.solvers.pbd.solver import PBDSolver

    ps = 0.01
    scene = Scene.model_validate(
        {
            "sim": {"dim": 2, "dt": 2e-3, "substeps": 5},
            "domain": {"lower": [0, 0], "upper": [0.08, 0.3]},
            "solvers": {"pbd": {"particle_size": ps}},
            "entities": [
                {
                    "name": "w",
                    "material": {"type": "PBD.Liquid", "rho": 1000, "vorticity_confinement": 0.01},
                    "morph": {"type": "Box", "lower": [0, 0], "upper": [0.08, 0.08]},
                }
            ],
        }
    )
    s = PBDSolver(scene, [])
    s.build()
    assert s.counts()["particles"] == 64
    assert s.mass.sum() == pytest.approx(1000 * 0.08**2)  # kg per metre of depth
    assert s.output_fields()["position"][0] == 2
    rho0 = s.liquids[0].rho0
    assert rho0 == pytest.approx(1000.0, rel=0.05)
    s.substep(4e-4)
    rho = s.entity_arrays("w", ["density"])["density"] / rho0
    below_top = s.x.to_numpy()[:, 1] < 0.07
    assert rho[below_top].min() > 0.996 and rho[below_top].max() < 1.001
    worst = 0.0
    for k in range(500):  # 0.2 s
        s.substep(4e-4)
        if k % 50 == 49:
            worst = max(worst, float(s.entity_arrays("w", ["density"])["density"].max()))
    assert worst < 1.01 * rho0
    x = s.x.to_numpy()
    assert x.shape == (64, 2)
    assert abs(x[:, 1].max() - 0.075) < 0.5 * ps  # the top layer stays where it was
    assert np.abs(s.v.to_numpy()).max() < 0.3
    assert x[:, 1].min() >= 0.5 * ps - 1e-6 and x[:, 0].max() <= 0.08 - 0.5 * ps + 1e-6


def test_2d_grains_rest_on_a_disk_and_the_floor(ti_f32):
    from simcli.scene.models import Scene
    from simcli.solvers.pbd.solver import PBDSolver

    ps = 0.01
    scene = Scene.model_validate(
        {
            "sim": {"dim": 2, "dt": 2e-3, "substeps": 5},
            "domain": {"lower": [0, 0], "upper": [0.2, 0.2]},
            "solvers": {"pbd": {"particle_size": ps}},
            "colliders": [{"type": "Sphere", "center": [0.1, 0.05], "radius": 0.03}],
            "entities": [
                {
                    "name": "g",
                    "material": {"type": "PBD.Particle", "rho": 1500, "static_friction": 0.5},
                    "morph": {"type": "Box", "lower": [0.05, 0.1], "upper": [0.15, 0.15]},
                }
            ],
        }
    )
    s = PBDSolver(scene, [])
    s.build()
    assert s.mass.sum() == pytest.approx(1500 * 0.1 * 0.05)
    for _ in range(1500):  # 0.6 s
        s.substep(4e-4)
    x = s.x.to_numpy()
    assert np.isfinite(x).all() and x.shape[1] == 2
    assert x[:, 1].min() >= 0.5 * ps - 1e-6 and x.min() >= -1e-9 and x.max() <= 0.2 + 1e-9
    assert (np.linalg.norm(x - [0.1, 0.05], axis=1) >= 0.03 + 0.5 * ps - 1e-4).all()  # none in the disk
    assert x[:, 1].max() < 0.15  # they fell
    d = np.linalg.norm(x[:, None] - x[None], axis=-1) + np.eye(len(x))
    assert d.min() > 0.8 * ps  # contact keeps them apart
    assert np.abs(s.v.to_numpy()).max() < 0.1  # at rest


FLOAT_PBF = textwrap.dedent(
    """\
    version: 1
    sim: {dim: 2, dt: 2.0e-3, substeps: 5, duration: 0.6}
    domain: {lower: [0.0, 0.0], upper: [0.16, 0.12], boundary: {type: slip}}
    solvers:
      pbd: {particle_size: 0.005}
    entities:
      - name: water
        material: {type: PBD.Liquid, rho: 1000, viscosity_relaxation: 0.05}
        morph: {type: Box, lower: [0.0, 0.0], upper: [0.16, 0.05]}
    rigid_bodies:
      - name: raft
        morph: {type: Box, center: [0.08, 0.062], size: [0.04, 0.02]}
        rho: 500
        fixed_dofs: [rz]
    output: {every: 10, formats: [hdf5], fields: [position]}
    """
)


@pytest.mark.slow  # ~95 s on the shared 2-core machine (load 15), most of it compiling
def test_a_box_floats_on_2d_pbf_water(tmp_path):
    """Two-way PBF-rigid in 2D: a rho 500 raft dropped on PBD.Liquid settles; the liquid (counting the box's
    faces in its density) carries its weight and it floats with a draft near rho_b / rho_l x its height."""
    import h5py

    from simcli.verify.rigid_measures import rigid_draft

    scene = tmp_path / "float.yaml"
    scene.write_text(FLOAT_PBF)
    out = tmp_path / "out"
    r = _run(["run", str(scene), "-o", str(out), "-q"])
    assert r.returncode == 0, r.stderr
    weight = 500 * 0.04 * 0.02 * 9.81  # N per metre of depth
    with h5py.File(out / "sim.h5", "r") as f:
        t = f["time"][()]
        late = t >= 0.4
        force = f["rigid_bodies/raft/force"][()]
        vel = f["rigid_bodies/raft/velocity"][()]
        pos = f["rigid_bodies/raft/position"][()]
        assert np.isfinite(pos).all()
        assert force[late, 1].mean() == pytest.approx(weight, rel=0.1)
        assert np.abs(vel[late]).max() < 0.05
        _, draft = rigid_draft(f, "water", "raft", spacing=0.005, margin=0.01, level="mass")
        assert 0.0075 < draft[late].mean() < 0.0125


BASE_2D = """\
version: 1
sim: {dim: 2, dt: 1.0e-3, duration: 0.01}
domain: {lower: [0.0, 0.0], upper: [0.2, 0.2]}
entities:
  - name: w
    material: {type: PBD.Liquid}
    morph: {type: Box, lower: [0.0, 0.0], upper: [0.1, 0.05]}
"""


@pytest.mark.parametrize(
    "extra, where, words",
    [
        (
            "  - name: c\n    material: {type: PBD.Cloth}\n"
            "    morph: {type: Rectangle, center: [0.1, 0.1, 0.1], size: [0.05, 0.05]}\n",
            ":9:",
            "PBD.Cloth is 3D only",
        ),
        (
            "  - name: r\n    material: {type: PBD.Elastic}\n"
            "    morph: {type: Box, lower: [0.1, 0.1], upper: [0.15, 0.15]}\n",
            ":9:",
            "PBD.Elastic is 3D only",
        ),
        (
            "  - name: s\n    material: {type: SPH.Liquid}\n"
            "    morph: {type: Box, lower: [0.1, 0.1], upper: [0.15, 0.15]}\n",
            ":6:",
            "coupling PBD with SPH is 3D only",
        ),
        (
            "emitters:\n  - name: jet\n    material: {type: SPH.Liquid, rho: 1000}\n"
            "    shape: {type: Rectangle, center: [0.1, 0.15], size: [0.02], normal: [0, -1]}\n"
            "    speed: 1.0\n    max_particles: 100\n",
            ":6:",
            "coupling PBD with SPH is 3D only",
        ),
        (
            "    fixed: {type: Cylinder, center: [0.05, 0.0, 0.0], radius: 0.01, height: 0.01}\n",
            ":8:",
            "Cylinder regions need dim 3",
        ),
    ],
    ids=["cloth", "elastic", "coupling", "coupling_by_emitter", "cylinder_region"],
)
def test_3d_only_pbd_in_2d_is_refused_with_its_location(tmp_path, extra, where, words):
    scene = tmp_path / "bad.yaml"
    scene.write_text(BASE_2D + extra)
    r = _run(["validate", str(scene)])
    assert r.returncode == 65, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if words in ln]
    assert lines and where in lines[0], r.stderr
    assert "Traceback" not in r.stderr


def test_2d_pool_drained_by_a_sink_and_fed_by_an_emitter(tmp_path):
    """A 2D PBF pool under gravity with a sink in one bottom corner and a PBD.Liquid jet above it: the sink
    takes mass out, the jet brings rho A v t in (per metre of depth), and the scene's mass (a total probe)
    is the start's plus what entered minus what left."""
    import h5py

    scene = tmp_path / "pool.yaml"
    scene.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 2, dt: 2.0e-3, steps: 40, substeps: 4}
            domain: {lower: [0.0, 0.0], upper: [0.2, 0.2], boundary: {type: slip}}
            solvers: {pbd: {particle_size: 0.005, density_iterations: 3}}
            entities:
              - name: pool
                material: {type: PBD.Liquid, rho: 1000}
                morph: {type: Box, lower: [0.0, 0.0], upper: [0.2, 0.04]}
            emitters:
              - name: jet
                material: {type: PBD.Liquid, rho: 1000}
                shape: {type: Rectangle, center: [0.15, 0.15], size: [0.02], normal: [0, -1]}
                speed: 1.0
                max_particles: 400
            sinks:
              - {name: drain, type: Box, lower: [0.0, 0.0], upper: [0.03, 0.02]}
            probes:
              - {name: mass, type: total, quantity: mass, entity: "*", every: 10}
            output: {every: 10, formats: [hdf5]}
            """
        )
    )
    r = _run(["run", str(scene), "-o", str(tmp_path / "out"), "--quiet"])
    assert r.returncode == 0, r.stderr
    with h5py.File(tmp_path / "out" / "sim.h5", "r", swmr=True) as f:
        t = f["time"][:]
        emitted = f["emitters/jet/emitted_mass"][:]
        removed = f["sinks/drain/removed_mass"][:]
        pool = f["entities/pool/count"][:]
        m = f["probes/mass/value"][:]
    start = 1000.0 * 0.2 * 0.04  # kg per metre of depth
    assert m[0] == pytest.approx(start, rel=1e-6)
    assert emitted[-1] == pytest.approx(1000.0 * 0.02 * 1.0 * t[-1], rel=0.02)
    assert removed[-1] > 0.2 and pool[-1] < pool[0]  # the corner's particles and those flowing into it
    assert m[-1] == pytest.approx(start + emitted[-1] - removed[-1], rel=1e-5)


def test_2d_pbd_with_coupling_off_and_a_cylinder_morph(tmp_path):
    scene = tmp_path / "ok.yaml"
    scene.write_text(
        BASE_2D
        + "  - name: s\n    material: {type: SPH.Liquid}\n"
        + "    morph: {type: Box, lower: [0.1, 0.1], upper: [0.15, 0.15]}\n"
        + "coupling: {sph_pbd: false}\n"
    )
    r = _run(["validate", str(scene)])
    assert r.returncode == 0, r.stderr
    scene.write_text(
        BASE_2D.replace(
            "type: Box, lower: [0.0, 0.0], upper: [0.1, 0.05]",
            "type: Cylinder, center: [0.05, 0.05], radius: 0.02, height: 0.02",
        )
    )
    r = _run(["validate", str(scene)])
    assert r.returncode == 65 and "Box or Sphere morphs" in r.stderr, r.stderr


def test_a_disk_body_on_2d_pbf_is_warned_about(tmp_path):
    """A 2D Sphere body over-counts in PBD.Liquid's density (docs/PBD.md, Gaps): validate says so, at its
    morph's type, and still accepts the scene."""
    scene = tmp_path / "disk.yaml"
    scene.write_text(
        BASE_2D
        + "rigid_bodies:\n  - name: disk\n    rho: 400\n"
        + "    morph: {type: Sphere, center: [0.1, 0.12], radius: 0.02}\n"
    )
    r = _run(["validate", str(scene)])
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if "warning" in ln and "Sphere (disk)" in ln]
    assert lines and ":11:" in lines[0], r.stderr
