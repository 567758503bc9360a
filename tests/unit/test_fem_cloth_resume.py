"""FEM.Cloth checkpoint/resume: a run resumed from a mid-run checkpoint writes the same frames as the
uninterrupted run, bit for bit (state: positions, velocities, time and IPC's adaptive barrier stiffness)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ipctk")
pytest.importorskip("scipy")

ROOT = Path(__file__).resolve().parents[2]

SCENE = textwrap.dedent(
    """\
    version: 1
    sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.08}
    domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 0.5], boundary: {type: slip, friction: 0.5}}
    colliders:
      - {type: Sphere, center: [0, 0, 0.1], radius: 0.05, friction: 0.3}
    solvers:
      fem: {contact_distance: 2.0e-3}
    entities:
      - name: a
        material: {type: FEM.Cloth, E: 1.0e5, rho: 200, thickness: 1.0e-3, friction: 0.3, damping: 0.5}
        morph: {type: Rectangle, center: [0.01, 0, 0.17], size: [0.2, 0.2], resolution: 4}
        velocity: [0.1, 0, -0.5]
    output: {every: 1, formats: [hdf5]}
    checkpoint: {every: 2, keep: 10}
    """
)


def _run(args):
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args], capture_output=True, text=True, timeout=300, cwd=ROOT
    )


def test_resume_equals_the_uninterrupted_run_bit_for_bit(tmp_path):
    import h5py

    scene = tmp_path / "cloth.yaml"
    scene.write_text(SCENE)
    out = tmp_path / "out"
    r = _run(["run", str(scene), "-o", str(out), "-q"])
    assert r.returncode == 0, r.stderr
    keys = ("entities/a/position", "entities/a/velocity")
    with h5py.File(out / "sim.h5", "r") as f:
        full = {k: f[k][()] for k in keys}
        t_full = f["time"][()]
    assert len(t_full) == 9 and np.isfinite(full["entities/a/position"]).all()
    # the sheet landed on the sphere (barrier and lagged friction active) before the resume point
    info = json.loads((out / "run.json").read_text())["solvers"]["fem_cloth"]
    assert info["max_contacts"] > 0
    x = full["entities/a/position"]
    from simcli.solvers.fem.cloth.obstacles import FACET_STRETCH

    # resting within 3 mm of the facet stand-off its 5 cm cells (enclosing radius: half the diagonal) keep
    off = np.sqrt(0.05**2 + (FACET_STRETCH * 0.05 * np.sqrt(0.5)) ** 2) - 0.05
    assert np.linalg.norm(x[-1] - [0, 0, 0.1], axis=1).min() < 0.05 + off + 0.003
    ckpts = sorted((out / "checkpoints").glob("ckpt_*.npz"))
    assert len(ckpts) >= 3
    for p in ckpts[2:]:  # resume from the checkpoint at step 4
        p.unlink()
    r = _run(["run", str(scene), "-o", str(out), "--resume", "-q"])
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        assert np.array_equal(f["time"][()], t_full)
        for k, v in full.items():
            assert np.array_equal(f[k][()], v), k
