"""An explicitly requested GPU backend that the machine lacks is an error, not a silent CPU run."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from simcli.backend import _has_gpu_driver

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(_has_gpu_driver(), reason="this machine has a GPU driver")
def test_missing_cuda_is_an_error_not_a_cpu_fallback(tmp_path):
    out = tmp_path / "out"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "simcli",
            "run",
            str(ROOT / "configs" / "jelly_2d.yaml"),
            "-o",
            str(out),
            "--backend",
            "cuda",
            "--set",
            "sim.duration=0.01",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 1, r.stderr
    assert "backend 'cuda' requested but not available" in r.stderr and "--backend auto" in r.stderr
    assert "Traceback" not in r.stderr
    rj = json.loads((out / "run.json").read_text())
    assert rj["status"] == "failed" and rj["exit_code"] == 1
