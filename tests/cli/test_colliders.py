"""Issue 19 through the command line: named and moving colliders leave their loads in sim.h5, run.json
and the closing log, and their surfaces in vtk/<name>.pvd; resuming keeps the loads' frames; bad
motions are refused with exit 65 and the location."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET

import h5py
import numpy as np

SCENE = """\
version: 1
sim: {dim: 2, dt: 2.0e-3, substeps: 4, steps: 20}
domain: {lower: [0, 0], upper: [1, 0.5]}
colliders:
  - {name: table, type: Box, lower: [0.2, 0.0], upper: [0.8, 0.1]}
  - type: Sphere
    center: [0.1, 0.3]
    radius: 0.05
    motion: {keyframes: {times: [0, 0.04], translate: [[0, 0], [0.02, 0]], rotate: [[0], [90]]}}
solvers: {mpm: {grid_density: 32}}
entities:
  - name: block
    material: {type: MPM.Elastic, E: 2.0e5, nu: 0.3, rho: 1000}
    morph: {type: Box, lower: [0.4, 0.1], upper: [0.6, 0.2]}
output: {every: 2, formats: [hdf5, vtk]}
"""


def _run(args, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args], capture_output=True, text=True, timeout=timeout
    )


def test_named_and_moving_colliders_outputs(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    out = tmp_path / "out"
    r = _run(["run", str(scene), "-o", str(out), "--json"])
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert set(info["colliders"]) == {"table"}
    assert "collider 'table': force (" in r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        force, torque = f["colliders/table/force"][...], f["colliders/table/torque"][...]
        assert force.shape == (11, 2) and torque.shape == (11, 1)
        assert f["colliders/table/force"].attrs["unit"] == "N"
        assert np.all(force[0] == 0) and np.isfinite(force).all()
        assert force[1:, 1].min() < 0  # the block lands on the table: pushed down
    assert np.allclose(info["colliders"]["table"]["force_N"], force[-1])
    for name in ("table", "collider1"):
        files = [d.get("file") for d in ET.parse(out / "vtk" / f"{name}.pvd").getroot().iter("DataSet")]
        assert len(files) == 11 and all((out / "vtk" / p).exists() for p in files)
    # the sphere's last surface: moved by 0.02 m along x at t = 0.04 s
    text = (out / "vtk" / "collider1" / "collider1_000010.vtp").read_text()
    pts = np.array(text.split("<Points>")[1].split(">")[1].split("<")[0].split(), float).reshape(-1, 3)
    assert np.allclose(pts[:, :2].mean(axis=0), [0.12, 0.3], atol=1e-9)


def test_bad_motions_exit_65_with_location(tmp_path):
    (tmp_path / "m.csv").write_text("t,x,y,qw,qx,qy,qz\n0,0,0,1,0,0,0\n")
    bad = SCENE.replace(
        "motion: {keyframes: {times: [0, 0.04], translate: [[0, 0], [0.02, 0]], rotate: [[0], [90]]}}",
        "motion: {keyframes: {times: [0, 0.04, 0.02]}}",
    ).replace(
        "  - {name: table,",
        "  - {type: Sphere, center: [0.5, 0.4], radius: 0.02, motion: {file: m.csv}}\n"
        "  - {type: Sphere, center: [0.9, 0.4], radius: 0.02, motion: {linear_velocity: [10, 0]}}\n"
        "  - {name: table,",
    )
    scene = tmp_path / "scene.yaml"
    scene.write_text(bad)
    r = _run(["validate", str(scene)])
    assert r.returncode == 65, r.stderr
    err = r.stdout + r.stderr
    assert "Traceback" not in err
    assert f"{scene}:5:" in err and "missing column(s) z" in err
    assert f"{scene}:6:" in err and "leaves the domain" in err
    assert f"{scene}:11:" in err and "keyframe times must increase" in err  # the motion: line of item 3
    r = _run(["run", str(scene), "-o", str(tmp_path / "out")])
    assert r.returncode == 65 and "Traceback" not in r.stderr


def test_moving_named_colliders_validate_for_sph_and_sf(tmp_path):
    """SPH and SF move colliders and read their loads (issue 19): no longer refused."""
    sph = """\
version: 1
sim: {dim: 2, dt: 2.0e-3, steps: 2}
domain: {lower: [0, 0], upper: [0.4, 0.2]}
colliders:
  - {name: piston, type: Box, lower: [0.0, 0.0], upper: [0.04, 0.2], motion: {linear_velocity: [0.2, 0]}}
solvers: {sph: {particle_size: 0.01}}
entities:
  - name: water
    material: {type: SPH.Liquid, rho: 1000}
    morph: {type: Box, lower: [0.05, 0.0], upper: [0.3, 0.1]}
"""
    sf = """\
version: 1
sim: {dim: 2, dt: 0.01, steps: 2}
domain: {lower: [0, 0], upper: [1, 1]}
colliders:
  - {name: disk, type: Sphere, center: [0.3, 0.5], radius: 0.1, motion: {linear_velocity: [1, 0]}}
solvers: {sf: {resolution: 16}}
entities:
  - {name: air, material: {type: SF.Smoke}}
"""
    for name, text in (("sph.yaml", sph), ("sf.yaml", sf)):
        scene = tmp_path / name
        scene.write_text(text)
        r = _run(["validate", str(scene)])
        assert r.returncode == 0, r.stdout + r.stderr
