"""Stable fluids end to end (the CLI, as a user runs it): divergence below the tolerance on every
substep with jets, buoyancy, a collider and an open face; grid output (sim.h5 with origin and
spacing, .vti files); the mirror symmetry of a symmetric 3D plume (slow). The references (cavity vs
Ghia, Taylor-Green, a tank at rest) are validation cases: `simcli verify --tag sf`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]


def run(scene: Path, out: Path, *sets: str) -> dict:
    cmd = [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(out), "-q"]
    for s in sets:
        cmd += ["--set", s]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads((out / "run.json").read_text())


def test_plume_divergence_below_tolerance_every_substep_and_grid_output(tmp_path):
    out = tmp_path / "plume"
    info = run(
        ROOT / "configs" / "examples" / "sf_plume_2d.yaml",
        out,
        "sim.duration=1.0",
        "solvers.sf.resolution=64",
        "output.every=10",
    )
    sf = info["solvers"]["sf"]
    tol = sf["tolerance"]
    res = sf["per_substep"]["residual"]
    assert len(res) == 50 and max(res) <= tol and sf["steps_above_tolerance"] == 0
    assert info["counts"]["sf"]["cells"] == 32 * 64 and info["throughput"]["cell_substeps_per_s"] > 0
    with h5py.File(out / "sim.h5", "r") as f:
        g = f["entities/smoke"]
        assert g.attrs["kind"] == "grid" and tuple(g.attrs["grid_shape"]) == (32, 64)
        assert np.allclose(g.attrs["origin"], [0, 0]) and np.allclose(g.attrs["spacing"], [1 / 32, 1 / 32])
        assert g["velocity"].shape == (6, 64, 32, 2) and g["pressure"].attrs["unit"] == "Pa"
        div = np.abs(g["divergence"][1:]).max()
        dens = g["density"][-1]
        dt = yaml.safe_load(f.attrs["scene"])["sim"]["dt"]
    assert div * dt <= tol * 1.05 + 1e-7
    # hot smoke rose from the jet (y = 0.15) above 0.5 m in 1 s, and none is inside the obstacle
    rows = np.nonzero(dens.max(axis=1) > 0.05)[0]
    assert rows.max() * (1 / 32) > 0.5 and dens[38, 16] == 0.0
    assert (out / "vtk" / "smoke.pvd").exists() and len(list((out / "vtk" / "smoke").glob("*.vti"))) == 6


def test_stratified_tank_at_rest_keeps_its_smoke_in_place(tmp_path):
    """Heavy smoke in the lower half of a closed tank under gravity: buoyancy is a pure pressure
    gradient, so the fluid must stay at rest and the layer where it is. (Adding the body force before
    advecting carried the smoke by the unprojected, sinking velocity: 0.48 of the interface cells'
    smoke gone in 2 s.)"""
    out = tmp_path / "rest"
    run(
        ROOT / "configs" / "validation" / "sf_rest.yaml",
        out,
        "solvers.sf.resolution=32",
        "sim.duration=2.0",
        "output.every=100",
    )
    with h5py.File(out / "sim.h5", "r") as f:
        d = f["entities/tank/density"][...]
        v = f["entities/tank/velocity"][...]
    assert d.shape[0] == 3 and d[0].sum() > 0
    assert np.abs(d - d[0]).max() <= 1e-4
    assert np.abs(v).max() <= 1e-5


def test_run_stops_at_steady_state(tmp_path):
    """solvers.sf.steady_tolerance ends a run once the flow stops changing: the coarse cavity settles
    long before the 40 s cap; the last frame is written, and run.json says why it stopped."""
    out = tmp_path / "cav"
    info = run(
        ROOT / "configs" / "validation" / "sf_cavity_fast.yaml",
        out,
        "solvers.sf.resolution=16",
        "sim.dt=0.08",
        "sim.duration=40.0",
        "output.every=25",
        "solvers.sf.steady_tolerance=1.0e-3",
    )
    stop = info["stopped_steady"]
    assert info["status"] == "done" and stop["change_rate"] <= 1.0e-3 and 4.0 < stop["time"] < 40.0
    assert info["sim_time"] == pytest.approx(stop["time"])
    with h5py.File(out / "sim.h5", "r") as f:
        t = f["time"][...]
        v = f["entities/fluid/velocity"][...].astype(np.float64)
    assert t[-1] == pytest.approx(stop["time"])
    # the same criterion on the written (cell-centred) velocities: settled at the end, not before
    rate = np.abs(np.diff(v, axis=0)).reshape(len(t) - 1, -1).max(axis=1) / np.diff(t)
    assert rate[-1] <= 1.5e-3 and rate[0] > 1.0e-2


@pytest.mark.slow
def test_symmetric_plume_stays_symmetric_3d(tmp_path):
    """A jet on the axis of a square box with a centred collider: the flow must stay mirror-symmetric
    in x and y (to round-off and the red-black ordering of the smoother)."""
    scene = tmp_path / "sym.yaml"
    scene.write_text(
        yaml.safe_dump(
            {
                "version": 1,
                "sim": {"dim": 3, "dt": 0.02, "substeps": 1, "steps": 40},
                "domain": {
                    "lower": [-0.5, -0.5, 0.0],
                    "upper": [0.5, 0.5, 1.0],
                    "boundary": {"type": "slip"},
                    "faces": {"z+": {"type": "open"}},
                },
                "colliders": [{"type": "Box", "lower": [-0.2, -0.2, 0.5], "upper": [0.2, 0.2, 0.6]}],
                "solvers": {"sf": {"resolution": 32}},
                "entities": [
                    {
                        "name": "smoke",
                        "material": {"type": "SF.Smoke", "thermal_expansion": 0.00341},
                        "jets": [
                            {
                                "position": [0.0, 0.0, 0.1],
                                "radius": 0.08,
                                "velocity": [0, 0, 1.0],
                                "density_rate": 5.0,
                                "temperature_rate": 200.0,
                            }
                        ],
                    }
                ],
                "output": {"every": 40, "formats": ["hdf5"], "fields": ["velocity", "density"]},
            }
        )
    )
    run(scene, tmp_path / "out")
    with h5py.File(tmp_path / "out" / "sim.h5", "r") as f:
        d = f["entities/smoke/density"][-1]  # (z, y, x)
        w = f["entities/smoke/velocity"][-1, ..., 2]
    scale = np.abs(d).max()
    assert scale > 0.1
    assert np.abs(d - d[:, :, ::-1]).max() <= 1e-3 * scale and np.abs(d - d[:, ::-1, :]).max() <= 1e-3 * scale
    assert np.abs(w - w[:, :, ::-1]).max() <= 1e-3 * np.abs(w).max()


def test_runaway_guard_fires_at_sf_max_cfl_with_sf_advice(tmp_path):
    """SF's runaway limit is its own solvers.sf.max_cfl (Solver.runaway_cfl), measured in real cells: the
    coarse cavity's lid flow crosses about half a cell per substep, so max_cfl 0.01 stops the run (exit
    70) with SF's advice, and a default max_cfl does not."""
    scene = ROOT / "configs" / "validation" / "sf_cavity_fast.yaml"
    sets = ["solvers.sf.resolution=16", "sim.dt=0.08", "sim.substeps=1", "sim.duration=0.8", "output.every=5"]
    cmd = [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(tmp_path / "a"), "-q"]
    for s in sets + ["solvers.sf.max_cfl=0.01"]:
        cmd += ["--set", s]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 70, r.stderr[-2000:]
    assert "solvers.sf.max_cfl (now 0.01" in r.stderr and "stiffness" not in r.stderr
    cells = float(r.stderr.split("crosses ")[1].split(" cells")[0])
    assert 0.01 < cells < 2.0  # the real cells per substep (no longer scaled by max_cfl / RUNAWAY_CFL)
    info = run(scene, tmp_path / "b", *sets)
    assert info["status"] == "done"
