"""Memory and disk estimates (simcli/scene/resources.py, summing each family's solvers/<family>/resources.py):
from the scene alone, refused with exit 65 naming the key to change, and never by allocating what they
estimate."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import pytest
from click.testing import CliRunner

from benchmarks.memory_estimates import CASES
from simcli.cli import cli
from simcli.runner import run_scene
from simcli.scene import resources
from simcli.scene.loader import load_scene

CLOTH = """\
version: 1
sim: {{dim: 3, dt: 4.0e-3, substeps: 10, duration: 1.5}}
domain: {{lower: [-1, -1, 0], upper: [1, 1, 1.5]}}
entities:
  - name: cloth
    material: {{type: PBD.Cloth, rho: 0.2}}
    morph: {{type: Rectangle, center: [0, 0, 0.8], size: [1.0, 1.0], resolution: {res}}}
"""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "scene.yaml"
    p.write_text(textwrap.dedent(text))
    return p


def _estimate(tmp_path: Path, text: str) -> resources.Estimate:
    loaded = load_scene(_write(tmp_path, text))
    return resources.estimate_memory(loaded.scene, loaded.scene_dir)


def test_huge_cloth_refused_without_allocating(tmp_path):
    """A 8000 x 8000 cloth (64 M vertices) is refused by validate with exit 65 naming its resolution; the
    check allocates nothing in proportion to it (the mesh alone would take gigabytes)."""
    p = _write(tmp_path, CLOTH.format(res=8000))
    tracemalloc.start()
    try:
        r = CliRunner().invoke(cli, ["validate", str(p)])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert r.exit_code == 65, r.output
    assert "entities.0.morph.resolution: scene too large" in r.output, r.output
    assert "64,016,001 vertices" in r.output, r.output
    assert f"{p}:7:" in r.output, r.output  # the location of the morph's resolution
    assert peak < 20 * 2**20, f"validate allocated {peak / 2**20:.0f} MiB"


def test_large_pbd_liquid_validated_without_sampling(tmp_path, monkeypatch):
    """A PBD.Liquid of 8 M particles under the memory limit validates (bounds checked analytically)
    without sampling its particles."""
    monkeypatch.setattr(resources, "available_memory", lambda: 1 << 45)
    text = """\
    version: 1
    sim: {{dim: 3, dt: 1.0e-3, substeps: 1, steps: 1}}
    domain: {{lower: [0, 0, 0], upper: [1, 1, 1]}}
    solvers: {{pbd: {{particle_size: 0.005}}}}
    entities:
      - name: water
        material: {{type: PBD.Liquid}}
        morph: {{type: Box, lower: [0, 0, 0], upper: [1, 1, {top}]}}
    """
    p = _write(tmp_path, text.format(top=1))
    tracemalloc.start()
    try:
        r = CliRunner().invoke(cli, ["validate", str(p)])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert r.exit_code == 0, r.output
    assert peak < 20 * 2**20, f"validate allocated {peak / 2**20:.0f} MiB"
    # a morph outside the domain is still found, from its bounds
    p = _write(tmp_path, text.format(top=1.2))
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 65 and "extends outside the domain along z" in r.output, r.output


@pytest.mark.parametrize("family", ["MPM", "SPH", "FEM", "PBD", "PBF", "SF"])
def test_estimate_grows_with_size(tmp_path, family):
    """Every family: a finer scene is estimated larger, and the estimate grows by more than the baseline
    (the per-element share is counted)."""
    make, sizes, _ = CASES[family]
    totals = []
    for s in sizes:
        est = _estimate(tmp_path, make(s))
        assert [p.family for p in est.parts] == ["PBD" if family == "PBF" else family]
        totals.append(est.total)
    assert all(a < b for a, b in zip(totals, totals[1:])), totals
    assert totals[-1] - totals[0] > 0.5 * totals[0], totals


@pytest.mark.parametrize(
    "family,key",
    [
        ("MPM", "solvers.mpm.grid_density"),
        ("SPH", "solvers.sph.particle_size"),
        ("FEM", "solvers.fem.resolution"),
        ("PBD", "entities.0.morph.resolution"),
        ("PBF", "solvers.pbd.particle_size"),
        ("SF", "solvers.sf.resolution"),
    ],
)
def test_over_the_limit_names_the_key(tmp_path, monkeypatch, family, key):
    """With less memory available than the estimate, validate says exit 65 with the key to change."""
    make, sizes, _ = CASES[family]
    p = _write(tmp_path, make(sizes[1]))
    loaded = load_scene(p)
    need = resources.estimate_memory(loaded.scene, loaded.scene_dir).total
    monkeypatch.setattr(resources, "available_memory", lambda: int(need / resources.MEMORY_FRACTION) - 1)
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 65, r.output
    assert f"{key}: scene too large" in r.output, r.output
    assert "Traceback" not in r.output
    monkeypatch.setattr(resources, "available_memory", lambda: int(need / resources.MEMORY_FRACTION) + 1)
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 0, r.output


def test_threads_multiply_the_mpm_grid(tmp_path):
    """MPM's P2G keeps a private grid per thread (up to 1 GiB): the estimate follows sim.threads."""
    text = CASES["MPM"][0](100)
    one = _estimate(tmp_path, text.replace("steps: 3}", "steps: 3, threads: 1}"))
    eight = _estimate(tmp_path, text.replace("steps: 3}", "steps: 3, threads: 8}"))
    nodes = 87 * 37 * 57  # ceil(0.8, 0.3, 0.5 x 100) + 7 per axis
    assert eight.total - one.total == 7 * nodes * 5 * 4


def test_disk_estimate_refuses_before_running(tmp_path, monkeypatch):
    """An output larger than the free space of the output folder: exit 65 before Taichi starts, naming
    output.every; half the free space: a warning, and the run goes on."""
    p = _write(tmp_path, CASES["FEM"][0](40))
    loaded = load_scene(p)
    est = resources.estimate_memory(loaded.scene, loaded.scene_dir)
    need = resources.estimate_disk(loaded.scene, est)
    assert need > 0
    monkeypatch.setattr(resources, "free_disk", lambda path: need // 2)
    code, info = run_scene(loaded, out_dir=tmp_path / "out", quiet=True)
    assert code == 65
    assert "output.every: the output needs about" in info["error"] and "output.formats" in info["error"], info
    assert not (tmp_path / "out" / "sim.h5").exists()
    found = resources.disk_problem(loaded.scene, loaded.scene_dir, tmp_path, 0)
    assert found is not None and found[0]
    monkeypatch.setattr(resources, "free_disk", lambda path: int(need / 0.75))
    found = resources.disk_problem(loaded.scene, loaded.scene_dir, tmp_path, 0)
    assert found is not None and not found[0]  # a warning only


def test_disk_estimate_bounds_the_written_output(tmp_path):
    """The estimate is an upper bound of what a run writes (hdf5 uncompressed, VTK zlib-compressed)."""
    pytest.importorskip("taichi")
    p = _write(tmp_path, CASES["FEM"][0](40))
    loaded = load_scene(p)
    need = resources.estimate_disk(loaded.scene, resources.estimate_memory(loaded.scene, loaded.scene_dir))
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(p), "-o", str(out), "-q"], capture_output=True
    )
    assert r.returncode == 0, r.stderr
    wrote = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    assert wrote <= need <= 3 * wrote, (wrote, need)


@pytest.mark.parametrize(
    "solvers,material,key",
    [
        ("{mpm: {grid_density: 64, particle_size: 1.0e-6}}", "MPM.Liquid", "solvers.mpm.grid_density"),
        ("{sph: {particle_size: 1.0e-6}}", "SPH.Liquid", "solvers.sph.particle_size"),
        ("{pbd: {particle_size: 1.0e-6}}", "PBD.Liquid", "solvers.pbd.particle_size"),
    ],
)
def test_absurd_spacing_is_too_large_not_an_overflow(tmp_path, solvers, material, key):
    """The smallest spacing the range check lets through (1e-6 m: 5e17 particles in this box, near int64's
    limit; smaller spacings are refused by the range check first) is refused as too large, not wrapped to
    0 particles (1e-30 used to validate 'ok')."""
    text = f"""\
    version: 1
    sim: {{dim: 3, dt: 1.0e-3, substeps: 1, steps: 1}}
    domain: {{lower: [0, 0, 0], upper: [1, 1, 1]}}
    solvers: {solvers}
    entities:
      - name: water
        material: {{type: {material}}}
        morph: {{type: Box, lower: [0, 0, 0], upper: [1, 1, 0.5]}}
    """
    r = CliRunner().invoke(cli, ["validate", str(_write(tmp_path, text))])
    assert r.exit_code == 65, r.output
    assert f"{key}: scene too large" in r.output, r.output


def test_checkpoints_count_the_state_copy(tmp_path):
    """With checkpoint.every > 0 the estimate holds the checkpoint's numpy copy of the state (MPM, 3D, f32:
    x, v, C, H and F in float64 plus Jp: 176 bytes a particle), and the disk estimate keeps
    checkpoint.keep."""
    make = CASES["MPM"][0]
    plain = _estimate(tmp_path, make(100))
    text = make(100).replace("output: {every: 1,", "checkpoint: {every: 2, keep: 3}\noutput: {every: 1,")
    ck = _estimate(tmp_path, text)
    n = 80_135  # particles of the 100 case
    assert ck.total - plain.total == n * 176
    loaded = load_scene(_write(tmp_path, text))
    disk = resources.estimate_disk(loaded.scene, ck)
    assert disk - resources.estimate_disk(load_scene(_write(tmp_path, make(100))).scene, plain) == 3 * n * 176
