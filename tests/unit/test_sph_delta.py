"""delta-SPH for WCSPH (simcli/solvers/sph/delta_sph.py): ``solvers.sph.density: continuity`` with
``density_diffusion`` and ``artificial_viscosity``.

* A small 2D tank released at rest with the continuity density (starting at the hydrostatic density) and
  Antuono's diffusion stays at rest (no start-up wave: its density is already the hydrostatic one) and
  reads the hydrostatic pressure at mid-depth within a few per cent; Fourtakis' variant too.
* The keys are refused where they do not apply (DFSPH; diffusion without the continuity density), exit 65
  with the location.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]

DEPTH = 0.04
SCENE = """
version: 1
name: delta_tank
sim: {{dim: 2, dt: 5.0e-3, substeps: auto, duration: 0.15}}
domain: {{lower: [0.0, 0.0], upper: [0.06, 0.06]}}
solvers:
  sph: {sph}
entities:
  - name: water
    material: {{type: SPH.Liquid, rho: 1000, mu: 0.001}}
    morph: {{type: Box, lower: [0.0, 0.0], upper: [0.06, {depth}]}}
output: {{every: 10, formats: [hdf5], fields: [position, velocity, pressure]}}
"""


def _run(tmp_path, text: str, cmd: str = "run"):
    scene = tmp_path / "s.yaml"
    scene.write_text(text)
    args = [sys.executable, "-m", "simcli", cmd, str(scene)]
    if cmd == "run":
        args += ["-o", str(tmp_path / "out")]
    return scene, subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=600)


@pytest.mark.slow  # about 20 s each, mostly the kernels' compile
@pytest.mark.parametrize("model", ["antuono", "fourtakis"])
def test_a_tank_at_rest_stays_at_rest_with_the_hydrostatic_pressure(tmp_path, model):
    sph = (
        "{particle_size: 0.004, pressure_solver: WCSPH, density: continuity, "
        f"density_diffusion: {{model: {model}, delta: 0.1}}, artificial_viscosity: 0.02}}"
    )
    _, r = _run(tmp_path, SCENE.format(sph=sph, depth=DEPTH))
    assert r.returncode == 0, r.stdout + r.stderr
    with h5py.File(tmp_path / "out" / "sim.h5", "r") as f:
        g = f["entities"]["water"]
        x = np.asarray(g["position"][-1])
        v = np.asarray(g["velocity"][-1])
        p = np.asarray(g["pressure"][-1])
    # at rest: the released tank hardly moves (its density starts hydrostatic); the same tank with the summed
    # density (solvers.sph.density: summation) starts from the lattice and reads 12-19 cm/s at most and
    # 4-5 cm/s on average by 0.15 s; here 1-1.5 cm/s at most, 0.1-0.5 cm/s on average
    speed = np.linalg.norm(v, axis=1)
    assert float(speed.max()) < 0.03
    assert float(speed.mean()) < 0.01
    # the hydrostatic pressure of the interior (away from the walls and the surface): a line through the
    # particles between 20% and 80% of the depth against rho0 g (H - z), H the top particle plus half a
    # spacing
    ps = 0.004
    z = x[:, 1]
    top = float(z.max()) + 0.5 * ps
    sel = (z > 0.2 * top) & (z < 0.8 * top) & (x[:, 0] > 2 * ps) & (x[:, 0] < 0.06 - 2 * ps)
    slope, icpt = np.polyfit(z[sel], p[sel], 1)
    zm = 0.5 * top
    expected = 1000.0 * 9.81 * (top - zm)
    assert abs((slope * zm + icpt) - expected) / expected < 0.03
    assert abs(-slope - 1000.0 * 9.81) / (1000.0 * 9.81) < 0.05


@pytest.mark.parametrize(
    "sph, needle",
    [
        ("{pressure_solver: DFSPH, density: continuity}", "WCSPH options"),
        ("{pressure_solver: WCSPH, density_diffusion: {model: antuono}}", "density: continuity"),
        ("{pressure_solver: WCSPH, density: continuity, density_diffusion: {model: ferrari}}", "model"),
    ],
)
def test_delta_sph_keys_are_refused_where_they_do_not_apply(tmp_path, sph, needle):
    scene, r = _run(tmp_path, SCENE.format(sph=sph, depth=DEPTH), "validate")
    assert r.returncode == 65, r.stdout + r.stderr
    msg = r.stdout + r.stderr
    assert needle in msg
    assert "s.yaml:" in msg  # the location
    assert "Traceback" not in msg


def test_a_resumed_continuity_run_continues_bit_for_bit(tmp_path):
    """The continuity density is state (it is integrated, not summed): a run resumed from a checkpoint
    continues exactly as the uninterrupted one. A column collapsing sideways, so the density moves."""
    import shutil

    sph = (
        "{particle_size: 0.004, pressure_solver: WCSPH, density: continuity, "
        "density_diffusion: {model: antuono, delta: 0.1}, artificial_viscosity: 0.02}"
    )
    text = (
        SCENE.format(sph=sph, depth=DEPTH)
        .replace("duration: 0.15", "duration: 0.02")
        .replace("upper: [0.06, 0.04]", "upper: [0.03, 0.04]")
        .replace("output: {every: 10,", "checkpoint: {every: 1, keep: 10}\noutput: {every: 1,")
    )
    assert "checkpoint" in text and "upper: [0.03, 0.04]" in text
    scene, r = _run(tmp_path, text)
    assert r.returncode == 0, r.stdout + r.stderr
    ref, out = tmp_path / "out", tmp_path / "resumed"
    shutil.copytree(ref, out)
    for p in (out / "checkpoints").glob("ckpt_*.npz"):
        if int(p.stem.split("_")[1]) > 2:
            p.unlink()
    args = [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(out), "-q", "--resume"]
    r = subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    with h5py.File(ref / "sim.h5", "r") as a, h5py.File(out / "sim.h5", "r") as b:
        assert list(a["step"][...]) == list(b["step"][...]) == [0, 1, 2, 3, 4]
        for k in ("position", "velocity", "pressure"):
            np.testing.assert_array_equal(b["entities/water"][k][...], a["entities/water"][k][...])
        v = np.asarray(a["entities/water/velocity"][-1])
    assert np.abs(v).max() > 0.05  # the column did move, so the density changed along the way


def test_the_continuity_density_starts_hydrostatic_in_each_supported_piece_of_a_column(tmp_path):
    """The start's depth is counted down each connected piece of a column: a pool under a falling drop
    starts with the pool's own head (not the drop's and the gap's), the drop with none (review: the pool's
    floor under the drop started at 3.8 kPa against 0.9 kPa beside it)."""
    sph = (
        "{particle_size: 0.004, pressure_solver: WCSPH, density: continuity, "
        "density_diffusion: {model: antuono, delta: 0.1}}"
    )
    text = (
        SCENE.format(sph=sph, depth=0.02)
        .replace("duration: 0.15", "duration: 0.005")
        .replace("upper: [0.06, 0.06]", "upper: [0.06, 0.12]")
        .replace(
            "output: {every: 10,",
            "  - name: drop\n"
            "    material: {type: SPH.Liquid, rho: 1000, mu: 0.001}\n"
            "    morph: {type: Box, lower: [0.02, 0.06], upper: [0.04, 0.1]}\n"
            "output: {every: 1,",
        )
    )
    _, r = _run(tmp_path, text)
    assert r.returncode == 0, r.stdout + r.stderr
    with h5py.File(tmp_path / "out" / "sim.h5", "r") as f:
        x = np.asarray(f["entities/water/position"][0])
        p = np.asarray(f["entities/water/pressure"][0])
        pd = np.asarray(f["entities/drop/pressure"][0])
    bottom = x[:, 1] < 0.004
    under = bottom & (np.abs(x[:, 0] - 0.03) < 0.008)
    beside = bottom & (np.abs(x[:, 0] - 0.03) > 0.02)
    assert under.any() and beside.any()
    head = 1000 * 9.81 * (0.02 - 0.002)  # the bottom row's depth below the pool's top
    assert abs(p[under].mean() - head) < 0.05 * head
    assert abs(p[under].mean() - p[beside].mean()) < 0.01 * head
    assert np.abs(pd).max() < 0.01 * head  # the drop, with nothing under it, starts unpressed
