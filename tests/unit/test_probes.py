"""Probes (issue 22): the sampling functions on synthetic arrays, the validate-time checks, sweep collect's
probe columns, and small runs that write probes.csv and sim.h5 /probes (also after --resume and SIGKILL)."""

from __future__ import annotations

import csv
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from simcli.probes import sampling

ROOT = Path(__file__).resolve().parents[2]


def _lattice(dim, spacing, lo, hi):
    axes = [np.arange(lo[a] + 0.5 * spacing, hi[a], spacing) for a in range(dim)]
    return np.stack([c.ravel() for c in np.meshgrid(*axes, indexing="ij")], axis=1)


# ------------------------------------------------------------------ sampling on synthetic arrays


@pytest.mark.parametrize("dim", [2, 3])
def test_kernel_average_of_a_hydrostatic_field_is_exact_inside(dim):
    """A field linear in z (p = rho g (H - z)) averaged with the symmetric kernel on a lattice gives its
    value at
    the point, and a constant field its constant, wherever the support is full."""
    s = 0.01
    x = _lattice(dim, s, [0.0] * dim, [0.2] * (dim - 1) + [0.1])
    p = 1000 * 9.81 * (0.1 - x[:, -1])
    at = [0.1] * (dim - 1) + [0.05]
    val = sampling.point_average(x, p, at, 2 * s)
    assert val == pytest.approx(1000 * 9.81 * 0.05, rel=1e-9)
    # off the lattice points too
    at2 = [0.1033] * (dim - 1) + [0.0517]
    assert sampling.point_average(x, p, at2, 2 * s) == pytest.approx(1000 * 9.81 * (0.1 - 0.0517), rel=2e-3)
    # volume weights that are all equal change nothing; vectors average per component
    v = np.tile(np.arange(1.0, dim + 1.0), (len(x), 1))
    assert np.allclose(
        sampling.point_average(x, v, at, 2 * s, np.full(len(x), 3.0)), np.arange(1.0, dim + 1.0)
    )


def test_kernel_average_is_nan_where_dry_and_sums_combine():
    x = np.array([[0.0, 0.0], [0.01, 0.0]])
    assert math.isnan(float(sampling.point_average(x, np.array([1.0, 2.0]), [0.5, 0.5], 0.02)))
    assert np.all(np.isnan(sampling.point_average(x, np.ones((2, 2)), [0.5, 0.5], 0.02)))
    assert math.isnan(float(sampling.point_average(np.zeros((0, 2)), np.zeros(0), [0, 0], 0.02)))
    # two entities combine through their sums: the same as one entity holding both
    n1, d1 = sampling.kernel_sums(x[:1], np.array([1.0]), [0.005, 0.0], 0.02)
    n2, d2 = sampling.kernel_sums(x[1:], np.array([2.0]), [0.005, 0.0], 0.02)
    both = sampling.point_average(x, np.array([1.0, 2.0]), [0.005, 0.0], 0.02)
    assert float(sampling.finish(n1 + n2, d1 + d2)) == pytest.approx(float(both)) == pytest.approx(1.5)


@pytest.mark.parametrize("dim", [2, 3])
def test_grid_interpolation_is_exact_for_linear_fields(dim):
    n = (8, 6, 5)[:dim]
    origin, spacing = (0.1, -0.2, 0.3)[:dim], (0.05, 0.1, 0.2)[:dim]
    centres = [origin[a] + (np.arange(n[a]) + 0.5) * spacing[a] for a in range(dim)]
    X = np.meshgrid(*centres, indexing="ij")  # x y z index order
    coef = (2.0, -3.0, 0.5)[:dim]
    f = 1.0 + sum(c * g for c, g in zip(coef, X))
    vtk = f.transpose(tuple(reversed(range(dim))))  # VTK order: (nz, ny, nx)
    at = [origin[a] + 0.37 * n[a] * spacing[a] for a in range(dim)]
    want = 1.0 + sum(c * p for c, p in zip(coef, at))
    assert float(sampling.grid_interpolate(vtk, origin, spacing, at)) == pytest.approx(want, rel=1e-12)
    # vector data (the last axis the components)
    vec = np.stack([vtk, 2 * vtk], axis=-1)
    assert np.allclose(sampling.grid_interpolate(vec, origin, spacing, at), [want, 2 * want])
    # at a cell centre: that cell's value
    c0 = [centres[a][1] for a in range(dim)]
    assert float(sampling.grid_interpolate(vtk, origin, spacing, c0)) == pytest.approx(f[(1,) * dim])


def test_surface_height_is_the_top_particle_plus_half_a_spacing_in_the_column():
    s = 0.01
    x = _lattice(3, s, [0, 0, 0], [0.2, 0.2, 0.1])
    # a higher particle outside the gauge's column is ignored; one inside counts
    x = np.vstack([x, [[0.15, 0.15, 0.18]]])
    assert sampling.surface_height(x, [0.05, 0.05], 2, s, 0.5 * s) == pytest.approx(0.1)
    assert sampling.surface_height(x, [0.151, 0.149], 2, s, 0.5 * s) == pytest.approx(0.185)
    assert math.isnan(sampling.surface_height(x, [0.5, 0.5], 2, s, 0.5 * s))
    # 2D, axis y; and a gauge along x
    x2 = _lattice(2, s, [0, 0], [0.3, 0.07])
    assert sampling.surface_height(x2, [0.1], 1, s, 0.5 * s) == pytest.approx(0.07)
    assert sampling.surface_height(x2, [0.03], 0, s, 0.5 * s) == pytest.approx(0.3)


def test_connected_surface_height_leaves_out_spray_above_the_liquid():
    s = 0.01
    x = _lattice(3, s, [0, 0, 0], [0.2, 0.2, 0.1])
    spray = [[0.15, 0.15, 0.18], [0.151, 0.15, 0.121]]  # a droplet 2.6 spacings above, one 2.1 above the top
    x = np.vstack([x, spray])
    at = [0.151, 0.149]
    assert sampling.surface_height(x, at, 2, s, 0.5 * s) == pytest.approx(0.185)  # highest: the spray
    assert sampling.surface_height(x, at, 2, s, 0.5 * s, gap=2 * s) == pytest.approx(0.1)
    # a particle within two spacings of the top is liquid (a wavy surface, a thin sheet)
    x = np.vstack([x, [[0.15, 0.15, 0.112]]])
    assert sampling.surface_height(x, at, 2, s, 0.5 * s, gap=2 * s) == pytest.approx(0.126)
    assert math.isnan(sampling.surface_height(x, [0.5, 0.5], 2, s, 0.5 * s, gap=2 * s))


def test_totals_from_masses_and_velocities():
    m = np.array([1.0, 2.0, 3.0])
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    v = np.array([[1.0, 0.0], [0.0, 2.0], [-1.0, -1.0]])
    assert float(sampling.finish_total("mass", *sampling.totals("mass", m))) == 6.0
    ke = 0.5 * (1 * 1 + 2 * 4 + 3 * 2)
    assert float(sampling.finish_total("kinetic_energy", *sampling.totals("kinetic_energy", m, v=v))) == ke
    assert np.allclose(sampling.finish_total("momentum", *sampling.totals("momentum", m, v=v)), [-2.0, 1.0])
    # com combines over entities through its sums
    s1, m1 = sampling.totals("com", m[:1], x=x[:1])
    s2, m2 = sampling.totals("com", m[1:], x=x[1:])
    assert np.allclose(sampling.finish_total("com", s1 + s2, m1 + m2), [2.0 / 6.0, 6.0 / 6.0])
    assert (
        float(sampling.finish_total("elastic_energy", *sampling.totals("elastic_energy", m, energy=[1, 2])))
        == 3
    )


# ------------------------------------------------------------------ validate-time checks


SPH_TANK = """\
version: 1
name: tank
sim: {dim: 2, dt: 2.0e-3, substeps: auto, steps: 10}
domain: {lower: [0.0, 0.0], upper: [0.2, 0.2]}
solvers:
  sph: {particle_size: 0.01, pressure_solver: DFSPH}
entities:
  - name: water
    material: {type: SPH.Liquid, rho: 1000}
    morph: {type: Box, lower: [0.0, 0.0], upper: [0.2, 0.1]}
output: {every: 5, formats: [hdf5]}
"""


def _validate(tmp_path, text):
    from simcli.errors import SceneError
    from simcli.scene.loader import load_scene

    f = tmp_path / "s.yaml"
    f.write_text(text)
    try:
        load_scene(f)
    except SceneError as e:
        return e.lines
    return []


def test_bad_probes_are_refused_with_their_location(tmp_path):
    lines = _validate(
        tmp_path,
        SPH_TANK
        + textwrap.dedent("""\
        probes:
          - {name: p1, type: point, quantity: pressure, position: [0.5, 0.05]}
          - {name: p1, type: point, quantity: velocity, position: [0.1, 0.05]}
          - {name: e, type: total, quantity: elastic_energy}
          - {name: k, type: total, quantity: mass, entity: nothere}
          - {name: h, type: height, position: [0.1, 0.2]}
        """),
    )
    text = "\n".join(lines)
    assert "s.yaml:13:" in text and "probes.0.position" in text and "outside the domain" in text
    assert "s.yaml:14:" in text and "duplicate probe name 'p1'" in text
    assert "probes.2.quantity" in text and "elastic_energy" in text and "MPM" in text
    assert "probes.3.entity" in text and "no entity named 'nothere'" in text
    assert "probes.4.position" in text and "height gauge" in text
    assert len(lines) == 5


def test_a_quantity_the_families_cannot_answer_is_refused(tmp_path):
    cloth = textwrap.dedent("""\
        version: 1
        sim: {dim: 3, steps: 2}
        entities:
          - name: sheet
            material: {type: PBD.Cloth}
            morph: {type: Rectangle, center: [0, 0, 0.5], size: [0.5, 0.5], resolution: [8, 8]}
        probes:
          - {name: p1, type: point, quantity: pressure, position: [0.0, 0.0, 0.3]}
          - {name: d, type: point, quantity: density, position: [0.0, 0.0, 0.3], entity: sheet}
          - {name: k, type: total, quantity: kinetic_energy}
        """)
    lines = _validate(tmp_path, cloth)
    assert len(lines) == 2, lines
    assert lines[0].startswith(f"{tmp_path / 's.yaml'}:8:") and "cannot answer" not in lines[0]
    assert "no entity of this scene (PBD.Cloth) can answer pressure" in lines[0]
    assert "entity 'sheet' (PBD.Cloth) cannot answer density" in lines[1]


def test_cli_validate_exits_65_for_a_probe_outside_the_domain(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(SPH_TANK + "probes:\n  - {name: p, type: point, quantity: density, position: [0.1, 0.3]}\n")
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(f)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )
    assert r.returncode == 65, r.stdout + r.stderr
    assert f"{f}:13:" in r.stderr + r.stdout and "outside the domain" in r.stderr + r.stdout
    assert "Traceback" not in r.stderr


# ------------------------------------------------------------------ sweep collect


def test_sweep_collect_picks_up_probe_columns(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from simcli.cli import cli

    monkeypatch.chdir(tmp_path)  # a sweep's output folder is relative to the working directory
    (tmp_path / "tank.yaml").write_text(SPH_TANK)
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        'version: 1\nbase: tank.yaml\noutput: out\nname: "n{sim.steps}"\ngrid: {sim.steps: [4, 6]}\n'
    )
    run0 = tmp_path / "out" / "n4"
    run0.mkdir(parents=True)
    (run0 / "probes.csv").write_text(
        "time,p,v.x,v.y\n0.0,1.0,,\n0.1,3.0,3.0,4.0\n0.2,nan,,\n0.3,2.0,0.0,-1.0\n"
    )
    r = CliRunner().invoke(
        cli, ["sweep", "collect", str(sweep), "-o", "-", "-m", "probe.v.y.min", "-m", "probe.v"]
    )
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(r.stdout.splitlines()))
    assert rows[0]["probe.p.final"] == "2.0" and rows[0]["probe.p.max"] == "3.0"  # NaN skipped
    assert rows[0]["probe.p.min"] == "1.0" and rows[0]["probe.p.mean"] == "2.0"
    assert rows[0]["probe.v.x.mean"] == "1.5" and rows[0]["probe.v.y.min"] == "-1.0"
    assert rows[0]["probe.v"] == "1.0"  # the magnitude of the last sample
    assert rows[1]["probe.p.final"] == ""  # no probes.csv in that run


# ------------------------------------------------------------------ runs


PROBES = """\
probes:
  - {name: p_mid, type: point, quantity: pressure, position: [0.1, 0.05], every: 2}
  - {name: v_mid, type: point, quantity: velocity, position: [0.1, 0.05]}
  - {name: h, type: height, position: [0.1]}
  - {name: mass, type: total, quantity: mass, entity: water}
  - {name: com, type: total, quantity: com}
"""


def _run(args, timeout=600):
    return subprocess.run(
        [sys.executable, "-m", "simcli", "run", *args, "--quiet"],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )


def _rows(path):
    with open(path) as f:
        return list(csv.reader(f))


def test_run_writes_probes_csv_and_h5_and_resume_does_not_repeat_rows(tmp_path):
    import h5py

    scene = tmp_path / "tank.yaml"
    scene.write_text(SPH_TANK + "checkpoint: {every: 4, keep: 5}\n" + PROBES)
    out = tmp_path / "out"
    r = _run([str(scene), "-o", str(out)])
    assert r.returncode == 0, r.stderr
    rows = _rows(out / "probes.csv")
    assert rows[0] == ["time", "p_mid", "v_mid.x", "v_mid.y", "h", "mass", "com.x", "com.y"]
    times = [float(r[0]) for r in rows[1:]]
    assert times == pytest.approx([0.0, 0.004, 0.008, 0.01, 0.012, 0.016, 0.02])  # every 2 steps and every 5
    by_t = {round(float(r[0]) / 0.002): r for r in rows[1:]}
    assert by_t[2][2:] == [""] * 6 and by_t[5][1] == ""  # a probe not due leaves its cells empty
    # a tank at rest: mass is rho x area (to the lattice normalisation), the level and the mid-depth pressure
    # are those of 0.1 m of water, the centre of mass is at the middle
    assert float(by_t[10][5]) == pytest.approx(1000 * 0.2 * 0.1, rel=2e-3)
    assert float(by_t[10][4]) == pytest.approx(0.1, abs=0.005)
    assert float(by_t[10][1]) == pytest.approx(1000 * 9.81 * 0.05, rel=0.15)
    assert float(by_t[10][6]) == pytest.approx(0.1, abs=1e-4) and float(by_t[10][7]) == pytest.approx(
        0.05, abs=5e-3
    )
    with h5py.File(out / "sim.h5", "r", swmr=True) as f:
        assert list(f["probes/p_mid/time"][:]) == pytest.approx([0.0, 0.004, 0.008, 0.012, 0.016, 0.02])
        assert f["probes/com/value"].shape == (3, 2) and f["probes/com/value"].attrs["unit"] == "m"
        assert f["probes/p_mid/value"].attrs["unit"] == "Pa"
        assert float(f["probes/h/value"][2]) == pytest.approx(float(by_t[10][4]))
    # resume from step 4's checkpoint: the rows after step 4 are dropped and written again, none repeated
    full = rows
    for p in (out / "checkpoints").glob("*00008*"):
        p.unlink()
    r = _run([str(scene), "-o", str(out), "--resume"])
    assert r.returncode == 0, r.stderr
    again = _rows(out / "probes.csv")
    assert [row[0] for row in again] == [row[0] for row in full]
    assert again == full  # the resumed run continues bit for bit (SPH checkpoints are exact)
    with h5py.File(out / "sim.h5", "r", swmr=True) as f:
        assert list(f["probes/p_mid/time"][:]) == pytest.approx([0.0, 0.004, 0.008, 0.012, 0.016, 0.02])
        assert f["probes/h/time"].shape == (3,)


def test_a_killed_run_keeps_its_probe_samples(tmp_path):
    import h5py

    scene = tmp_path / "tank.yaml"
    scene.write_text(
        SPH_TANK.replace("steps: 10", "steps: 100000")
        + "probes:\n  - {name: h, type: height, position: [0.1], every: 1}\n"
        + "  - {name: ke, type: total, quantity: kinetic_energy, every: 3}\n"
    )
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(out), "--quiet"],
        cwd=ROOT,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.time() + 400
        while time.time() < deadline:
            p = out / "probes.csv"
            if p.exists() and len(p.read_text().splitlines()) > 12:
                break
            if proc.poll() is not None:
                pytest.fail(f"run ended early with {proc.returncode}")
            time.sleep(0.2)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    lines = (out / "probes.csv").read_text().splitlines()
    rows = [ln.split(",") for ln in lines[1:] if ln.count(",") == 2]
    assert len(rows) >= 12
    steps = [round(float(r[0]) / 0.002) for r in rows]
    assert steps == list(range(len(rows)))  # every sample up to the kill, in order, none lost in a buffer
    assert all(r[1] and float(r[1]) == pytest.approx(0.1, abs=0.01) for r in rows)
    # sim.h5 gets the samples at frame steps (output.every = 5): every one up to its last complete frame
    with h5py.File(out / "sim.h5", "r", swmr=True) as f:
        last_frame_step = 5 * (f["time"].shape[0] - 1)
        n = f["probes/h/time"].shape[0]
        assert n >= last_frame_step + 1 and f["probes/h/value"].shape[0] >= n
        assert np.allclose(f["probes/h/time"][:n], [float(r[0]) for r in rows[:n]])
        assert np.allclose(f["probes/h/value"][:n], [float(r[1]) for r in rows[:n]])


def test_mpm_probes_answer_with_masses_momentum_and_the_liquid_level(tmp_path):
    scene = tmp_path / "mpm.yaml"
    scene.write_text(
        textwrap.dedent("""\
        version: 1
        sim: {dim: 2, dt: 2.0e-3, substeps: auto, steps: 10}
        domain: {lower: [0.0, 0.0], upper: [0.1, 0.3]}
        solvers:
          mpm: {grid_density: 100, particle_size: 0.005}
        entities:
          - name: water
            material: {type: MPM.Liquid, E: 1.0e6, nu: 0.2, rho: 1000, viscous: true, mu: 50.0}
            morph: {type: Box, lower: [0.0, 0.0], upper: [0.1, 0.2]}
          - name: jelly
            material: {type: MPM.Elastic, E: 1.0e5, nu: 0.3, rho: 500}
            morph: {type: Box, lower: [0.03, 0.23], upper: [0.07, 0.27]}
            velocity: [0.0, -1.0]
        output: {every: 5, formats: [hdf5]}
        probes:
          - {name: p, type: point, quantity: pressure, position: [0.05, 0.1], entity: water}
          - {name: rho, type: point, quantity: density, position: [0.05, 0.1]}
          - {name: v, type: point, quantity: velocity, position: [0.05, 0.25]}
          - {name: h, type: height, position: [0.01], entity: water}
          - {name: ee, type: total, quantity: elastic_energy}
          - {name: mom, type: total, quantity: momentum, entity: jelly}
          - {name: mass, type: total, quantity: mass}
          - {name: hc, type: height, position: [0.01], entity: water, surface: connected}
        """)
    )
    out = tmp_path / "out"
    r = _run([str(scene), "-o", str(out)])
    assert r.returncode == 0, r.stderr
    rows = _rows(out / "probes.csv")
    assert rows[0] == ["time", "p", "rho", "v.x", "v.y", "h", "ee", "mom.x", "mom.y", "mass", "hc"]
    first, last = [float(x) for x in rows[1]], [float(x) for x in rows[-1]]
    assert first[9] == pytest.approx(1000 * 0.1 * 0.2 + 500 * 0.04 * 0.04, rel=1e-6) == last[9]  # mass
    assert first[7:9] == pytest.approx([0.0, -0.8], abs=1e-6)  # jelly: 0.8 kg at -1 m/s
    assert first[3:5] == pytest.approx([0.0, -1.0], abs=1e-6)  # inside the jelly
    assert first[2] == pytest.approx(1000.0, rel=1e-6) and last[2] == pytest.approx(1000.0, rel=0.02)
    assert first[5] == pytest.approx(0.2, abs=1e-6) and last[5] == pytest.approx(0.2, abs=0.0025)
    assert first[6] == 0.0 and last[6] > 0.0  # the liquid's stored energy as it settles under gravity
    assert last[1] > 0.0
    # a calm liquid has no spray: the connected surface is the highest particle's
    assert [float(r[10]) for r in rows[1:]] == [float(r[5]) for r in rows[1:]]


def test_fem_totals_follow_free_fall(tmp_path):
    scene = tmp_path / "fem.yaml"
    scene.write_text(
        textwrap.dedent("""\
        version: 1
        sim: {dim: 3, dt: 2.0e-3, substeps: auto, steps: 5}
        solvers:
          fem: {integrator: explicit, resolution: 4}
        entities:
          - name: block
            material: {type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000, model: stable_neohookean}
            morph: {type: Box, lower: [-0.1, -0.1, 0.2], upper: [0.1, 0.1, 0.4]}
        output: {every: 5, formats: [hdf5]}
        probes:
          - {name: m, type: total, quantity: mass}
          - {name: mom, type: total, quantity: momentum}
          - {name: ke, type: total, quantity: kinetic_energy, every: 1}
          - {name: c, type: total, quantity: com, entity: block}
        """)
    )
    out = tmp_path / "out"
    r = _run([str(scene), "-o", str(out)])
    assert r.returncode == 0, r.stderr
    rows = _rows(out / "probes.csv")
    by_step = {round(float(r[0]) / 2e-3): r for r in rows[1:]}
    assert sorted(by_step) == [0, 1, 2, 3, 4, 5]
    m = float(by_step[5][1])
    assert m == pytest.approx(8.0, rel=1e-6)  # 0.2^3 m^3 of rho 1000
    t = 0.01
    assert float(by_step[5][4]) == pytest.approx(-m * 9.81 * t, rel=1e-3)  # momentum z: -m g t
    assert float(by_step[5][5]) == pytest.approx(0.5 * m * (9.81 * t) ** 2, rel=2e-3)
    # com z: symplectic Euler over N substeps drops 0.5 g t^2 (1 + 1/N), N >= 4 here
    drop = 0.3 - float(by_step[5][8])
    assert 0.5 * 9.81 * t**2 * (1 - 1e-3) < drop < 0.5 * 9.81 * t**2 * 1.25
    assert float(by_step[5][6]) == pytest.approx(0.0, abs=1e-9) and float(by_step[0][8]) == pytest.approx(0.3)


def test_a_height_gauge_reads_the_liquids_unless_it_names_an_entity(tmp_path):
    sand = textwrap.dedent("""\
        version: 1
        sim: {dim: 2, steps: 2}
        domain: {lower: [0.0, 0.0], upper: [0.2, 0.2]}
        entities:
          - name: heap
            material: {type: MPM.Sand}
            morph: {type: Box, lower: [0.0, 0.0], upper: [0.2, 0.1]}
        probes:
          - {name: h, type: height, position: [0.1]}
          - {name: h2, type: height, position: [0.1], entity: heap}
        """)
    lines = _validate(tmp_path, sand)
    assert len(lines) == 1 and ":9:" in lines[0] and "name the entity whose surface it measures" in lines[0]
    from simcli.probes.config import probe_entities
    from simcli.scene.models import Scene

    scene = Scene.model_validate(
        {
            "sim": {"dim": 2},
            "entities": [
                {
                    "name": "w",
                    "material": {"type": "MPM.Liquid"},
                    "morph": {"type": "Box", "lower": [0, 0], "upper": [1, 0.5]},
                },
                {
                    "name": "b",
                    "material": {"type": "MPM.Elastic"},
                    "morph": {"type": "Box", "lower": [0, 0.6], "upper": [1, 0.7]},
                },
            ],
            "probes": [{"name": "h", "type": "height", "position": [0.5]}],
        }
    )
    assert [e.name for e in probe_entities(scene, scene.probes[0])] == ["w"]  # not the floating block


def test_height_gauge_surface_is_highest_or_connected():
    from pydantic import ValidationError

    from simcli.probes.config import HeightProbe

    assert HeightProbe(name="h", type="height", position=[0.1]).surface == "highest"
    assert HeightProbe(name="h", type="height", position=[0.1], surface="connected").surface == "connected"
    with pytest.raises(ValidationError):
        HeightProbe(name="h", type="height", position=[0.1], surface="top")
