"""What a person reads: `--quiet` prints nothing of Taichi's, counts are in good English."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCENE = """\
version: 1
name: one
sim: {dim: 2, dt: 4.0e-3, substeps: 4, steps: 1, threads: 1}
domain: {lower: [0.0, 0.0], upper: [1.0, 1.0], boundary: {type: slip}}
solvers: {mpm: {grid_density: 16}}
entities:
  - name: blob
    material: {type: MPM.Elastic, E: 2.0e4, nu: 0.3, rho: 1000, model: neohooken}
    morph: {type: Box, lower: [0.4, 0.3], upper: [0.6, 0.5]}
output: {every: 1, formats: [hdf5]}
checkpoint: {every: 0}
"""


def _simcli(*args, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("ENABLE_TAICHI_HEADER_PRINT", None)  # as a user's shell has it: unset
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args], capture_output=True, text=True, timeout=600, cwd=cwd, env=env
    )


def test_one_entity_one_step_in_good_english(tmp_path):
    scene = tmp_path / "one.yaml"
    scene.write_text(SCENE)
    r = _simcli("validate", str(scene), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "ok (1 entity, dim 2, 1 step)" in r.stderr, r.stderr

    r = _simcli("run", str(scene), "-o", str(tmp_path / "out"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "done: 1 step, 2 frames in" in r.stderr, r.stderr
    assert not re.search(r"(?<![\d.])1 (steps|entities|frames)\b", r.stderr), r.stderr
    assert "[Taichi] version" not in r.stderr  # the import banner: never (run.json has the version)
    # the progress line's rate is run.json's (steps over stepping time)
    m = re.search(r"simcli: step 1/1 \(100\.0%\) t=\S+ ([\d.]+) steps/s ETA 0:00", r.stderr)
    assert m, r.stderr
    rj = json.loads((tmp_path / "out" / "run.json").read_text())
    assert float(m.group(1)) == pytest.approx(rj["throughput"]["steps_per_s"], abs=0.051)


def test_quiet_run_prints_nothing_of_taichi(tmp_path):
    scene = tmp_path / "one.yaml"
    scene.write_text(SCENE)
    r = _simcli("run", str(scene), "-o", str(tmp_path / "out"), "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""
    assert "[Taichi]" not in r.stderr, r.stderr
    assert "simcli: step" not in r.stderr and "done:" not in r.stderr
    assert r.stderr.strip() == "", r.stderr
