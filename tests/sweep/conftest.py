import os
import sys
import textwrap
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TINY = HERE / "data" / "tiny.yaml"


@pytest.fixture
def fake_sim(monkeypatch):
    """Tasks run the stand-in simulator (tests/sweep/fake_sim.py) instead of `simcli run`."""
    monkeypatch.setenv("SIMCLI_SWEEP_SIM_CMD", f"{sys.executable} {HERE / 'fake_sim.py'}")
    monkeypatch.setenv("PYTHONPATH", str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    monkeypatch.delenv("SLURM_ARRAY_TASK_ID", raising=False)
    monkeypatch.delenv("SLURM_CPUS_PER_TASK", raising=False)
    monkeypatch.delenv("FAKE_SIM_FAIL_AT", raising=False)
    monkeypatch.setenv("FAKE_SIM_STEP_S", "0.005")


@pytest.fixture
def make_sweep(tmp_path):
    """Write a sweep file (and a copy of the tiny scene) into tmp_path; returns its path."""

    def make(text: str, name: str = "sweep.yaml", scene: str | None = None) -> Path:
        (tmp_path / "tiny.yaml").write_text(scene if scene is not None else TINY.read_text())
        p = tmp_path / name
        p.write_text(textwrap.dedent(text))
        return p

    return make


def pytest_configure(config):
    # also registered in pyproject.toml; here so that --strict-markers accepts it either way
    config.addinivalue_line(
        "markers", "slurm: needs the Slurm binaries; starts a one-node cluster (pytest -m slurm)"
    )
