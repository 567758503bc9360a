"""MPM <-> SPH by boundary particles (simcli/coupling/mpm_sph.py): which scenes take it, the MPM body's
samples and short coupled runs.

* the rule: 3D scenes with SPH's boundary particles whose MPM entities are all solids with a fixed set of
  particles; 2D, volume maps, sand, liquid, emitters and sinks keep the grid contact;
* the samples of an MPM box are SPH's lattice in the box within the kernel's support of its surface;
* an MPM cube thrown at SPH water without gravity: the total momentum stays the cube's m v (the liquid's
  impulse on each sample goes to the MPM grid, reversed), energy does not grow beyond the explicit
  exchange's fraction of a per cent, the liquid never enters the body, and the two meet;
* liquid sampled inside an MPM body at the start is removed, and validate says so at the line;
* (slow) an FEM body and an MPM body in one liquid share SPH's samples (joined), momentum conserved;
  a checkpointed run resumes as the uninterrupted one.
"""

import csv
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from tests.physics.test_sph_fem_boundary import ROOT, _run, check_liquid_inside_removed

SCENE = """\
version: 1
name: mpm_sph_boundary
sim: {{dim: 3, dt: 2.0e-3, substeps: auto, duration: {duration}, gravity: [0.0, 0.0, 0.0]}}
domain: {{lower: [0.0, 0.0, 0.0], upper: [0.4, 0.3, 0.3]}}
solvers:
  sph: {{particle_size: 0.01, pressure_solver: {solver}}}
  mpm: {{grid_density: 100, particle_size: 0.005}}
{fem}entities:
  - name: block
    material: {{type: MPM.Elastic, E: 2.0e5, nu: 0.3, rho: 1000}}
    morph: {{type: Box, lower: [0.06, 0.12, 0.12], upper: [0.12, 0.18, 0.18]}}
    velocity: [1.0, 0.0, 0.0]
  - name: water
    material: {{type: SPH.Liquid, rho: 1000, mu: 0.01}}
    morph: {{type: Box, lower: [0.14, 0.12, 0.12], upper: [0.20, 0.18, 0.18]}}
{extra_entities}probes:
  - {{name: p, type: total, quantity: momentum, entity: "*", every: 1}}
  - {{name: ke, type: total, quantity: kinetic_energy, entity: "*", every: 1}}
  - {{name: ee, type: total, quantity: elastic_energy, entity: block, every: 1}}
{extra}output: {{every: {every}, fields: [position, velocity]}}
"""


def _text(duration=0.08, solver="WCSPH", every=5, extra="", fem="", extra_entities=""):
    return SCENE.format(
        duration=duration, solver=solver, every=every, extra=extra, fem=fem, extra_entities=extra_entities
    )


def _scene(text):
    import yaml

    from simcli.scene.models import Scene

    return Scene.model_validate(yaml.safe_load(text))


def test_the_rule_takes_boundary_particles_for_3d_solids_only():
    from simcli.scene.coupling import mpm_sph_by_particles

    text = _text()
    assert mpm_sph_by_particles(_scene(text))
    for mat in ("MPM.ElastoPlastic", "MPM.Snow"):
        assert mpm_sph_by_particles(_scene(text.replace("MPM.Elastic", mat)))
    # sand and liquid mix with the water: the grid contact
    assert not mpm_sph_by_particles(
        _scene(text.replace("type: MPM.Elastic, E: 2.0e5, nu: 0.3", "type: MPM.Sand"))
    )
    assert not mpm_sph_by_particles(
        _scene(text.replace("type: MPM.Elastic, E: 2.0e5, nu: 0.3", "type: MPM.Liquid"))
    )
    # volume maps hold no boundary particles to add the body to
    vm = text.replace("pressure_solver: WCSPH", "pressure_solver: WCSPH, boundary: volume_map")
    assert not mpm_sph_by_particles(_scene(vm))
    # a sink (the MPM particles' numbering changes as they leave) and the pair turned off
    sink = text.replace(
        "probes:", "sinks:\n  - {name: d, type: Box, lower: [0.3, 0.0, 0.0], upper: [0.4, 0.1, 0.1]}\nprobes:"
    )
    assert not mpm_sph_by_particles(_scene(sink))
    assert not mpm_sph_by_particles(_scene(text.replace("probes:", "coupling: {mpm_sph: false}\nprobes:")))
    # pinned MPM particles: a pinned node's velocity is reset every substep, the samples would drift
    pin = "    fixed: {type: Box, lower: [0.06, 0.12, 0.12], upper: [0.07, 0.18, 0.18]}\n"
    pinned = text.replace("    velocity: [1.0, 0.0, 0.0]\n", "    velocity: [1.0, 0.0, 0.0]\n" + pin, 1)
    assert "fixed:" in pinned and not mpm_sph_by_particles(_scene(pinned))


def test_the_samples_of_an_mpm_box_are_sphs_lattice_near_its_surface():
    from types import SimpleNamespace

    from simcli.coupling.mpm_sph import mpm_boundary_samples
    from simcli.geometry.sampling import sample_entity

    sc = _scene(_text())
    b = sample_entity(sc.entities[0], sc)
    mpm = SimpleNamespace(bodies=[b], dim=3, scene=sc)
    ps = 0.01
    x, v, vol = mpm_boundary_samples(mpm, ps, 2 * ps)
    # the cube is 0.06 m: SPH's lattice holds 6 x 6 x 6 = 216 points in it, of which the 2 x 2 x 2 centre
    # ones lie deeper than two spacings (their lattice distance to the outside is 2.5 spacings)
    assert len(x) == 216 - 8
    np.testing.assert_allclose(vol, ps**3, rtol=1e-9)
    cell = (x - np.array([0.06, 0.12, 0.12])) / ps - 0.5
    np.testing.assert_allclose(cell, np.round(cell), atol=1e-6)
    np.testing.assert_allclose(v, np.tile([1.0, 0.0, 0.0], (len(x), 1)))


def test_a_mesh_bodys_samples_lie_in_it():
    """C1's duck (a Mesh morph, configs/bench/c1_sph_mpm.yaml): SPH's lattice (0.02 m) falls on the faces
    between its particles' cells (0.01 m apart, their volumes scaled to the mesh's, a little under the
    lattice cell's): the samples are the lattice points within a particle's cell, faces included (none were
    kept before the spacing was read from the lattice), and none lies outside every particle's cell."""
    from types import SimpleNamespace

    from scipy.spatial import cKDTree

    from simcli.coupling.mpm_sph import mpm_boundary_samples
    from simcli.geometry.sampling import sample_entity
    from simcli.scene.loader import load_scene

    path = ROOT / "configs" / "bench" / "c1_sph_mpm.yaml"
    sc = load_scene(path, []).scene
    b = sample_entity(sc.entities[1], sc, scene_dir=path.parent)
    x, _, vol = mpm_boundary_samples(SimpleNamespace(bodies=[b], dim=3, scene=sc), 0.02, 0.04)
    d, _ = cKDTree(b.x).query(x, p=np.inf)
    assert len(x) > 300 and d.max() < 0.00501
    assert np.all(np.abs(vol / 0.02**3 - 1.0) < 0.1)  # the lattice cell, fitted to the duck's box


def _check_thrown(out, p0):
    rows = list(csv.DictReader(open(out / "probes.csv")))
    px = np.array([float(row["p.x"]) for row in rows])
    assert np.abs(px - p0).max() < 1e-3 * p0  # equal and opposite impulses (f32 sums)
    e = np.array([float(row["ke"]) + float(row["ee"]) for row in rows])
    assert e.max() < 1.005 * e[0]
    with h5py.File(out / "sim.h5", "r") as f:
        xb = np.asarray(f["entities/block/position"][...])
        vb = np.asarray(f["entities/block/velocity"][...])
        xw = np.asarray(f["entities/water/position"][...])
        vw = np.asarray(f["entities/water/velocity"][...])
    assert vb[-1][:, 0].mean() < 0.8  # the body was slowed and the liquid pushed: they met
    assert vw[-1][:, 0].mean() > 0.1
    # no liquid particle's centre inside the block's box shrunk by half an SPH spacing, at any frame
    for b, w in zip(xb, xw):
        lo, hi = b.min(axis=0) + 0.005 - 0.0025, b.max(axis=0) - 0.005 + 0.0025
        assert not np.any(np.all((w > lo) & (w < hi), axis=1))


def test_a_thrown_mpm_cube_meets_sph_water_momentum_conserved_and_no_liquid_inside(tmp_path):
    _, r = _run(tmp_path, _text())
    assert r.returncode == 0, r.stdout + r.stderr
    _check_thrown(tmp_path / "out", 1000 * 0.06**3 * 1.0)


@pytest.mark.slow
def test_a_thrown_mpm_cube_meets_dfsph_water(tmp_path):
    _, r = _run(tmp_path, _text(solver="DFSPH"))
    assert r.returncode == 0, r.stdout + r.stderr
    _check_thrown(tmp_path / "out", 1000 * 0.06**3 * 1.0)


def test_liquid_sampled_inside_an_mpm_body_is_removed_and_validate_says_so(tmp_path):
    """The MPM cube placed 2 cm into the water: validate warns at the water's morph that the liquid inside the
    cube is removed, and the run removes exactly the particles whose centres lie in the cube."""
    check_liquid_inside_removed(tmp_path, _text(duration=0.004, every=2), "MPM")


@pytest.mark.slow
def test_an_fem_and_an_mpm_body_share_the_liquids_samples(tmp_path):
    """Both bodies thrown at the water from either side: SPH holds one set of samples for both (joined), each
    pair reads its own; the total momentum is the two bodies' m v."""
    fem_entity = (
        "  - name: brick\n"
        "    material: {type: FEM.Elastic, E: 2.0e5, nu: 0.3, rho: 1000, model: stable_neohookean}\n"
        "    morph: {type: Box, lower: [0.22, 0.12, 0.12], upper: [0.28, 0.18, 0.18]}\n"
        "    velocity: [-0.5, 0.0, 0.0]\n"
    )
    text = _text(fem="  fem: {integrator: explicit, resolution: 100}\n", extra_entities=fem_entity)
    _, r = _run(tmp_path, text)
    assert r.returncode == 0, r.stdout + r.stderr
    rows = list(csv.DictReader(open(tmp_path / "out" / "probes.csv")))
    px = np.array([float(row["p.x"]) for row in rows])
    p0 = 1000 * 0.06**3 * (1.0 - 0.5)
    assert np.abs(px - p0).max() < 2e-3 * 1000 * 0.06**3
    with h5py.File(tmp_path / "out" / "sim.h5", "r") as f:
        vb = np.asarray(f["entities/block/velocity"][-1])
        vf = np.asarray(f["entities/brick/velocity"][-1])
    assert vb[:, 0].mean() < 0.8 and vf[:, 0].mean() > -0.4  # both met the liquid


@pytest.mark.slow
def test_a_coupled_mpm_sph_run_resumes_as_the_uninterrupted_one(tmp_path):
    text = _text(duration=0.04, extra="checkpoint: {every: 1, keep: 30}\n", every=2)
    scene, r = _run(tmp_path, text, ["--set", "sim.threads=1"])
    assert r.returncode == 0, r.stdout + r.stderr
    ref, out = tmp_path / "out", tmp_path / "resumed"
    shutil.copytree(ref, out)
    for p in (out / "checkpoints").glob("ckpt_*.npz"):
        if int(p.stem.split("_")[1]) > 4:
            p.unlink()
    args = [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(out), "-q", "--resume"]
    r = subprocess.run(
        [*args, "--set", "sim.threads=1"], capture_output=True, text=True, cwd=ROOT, timeout=900
    )
    assert r.returncode == 0, r.stdout + r.stderr
    with h5py.File(ref / "sim.h5", "r") as a, h5py.File(out / "sim.h5", "r") as b:
        assert list(a["step"][...]) == list(b["step"][...])
        for e in ("block", "water"):
            for k in ("position", "velocity"):
                np.testing.assert_array_equal(b[f"entities/{e}/{k}"][...], a[f"entities/{e}/{k}"][...])
