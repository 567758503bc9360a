"""Every class of bad input gives exit 65 and names the right file:line:column."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

from simcli.cli import cli

GOOD = """\
version: 1
sim: {dim: 3, dt: 2.0e-3, substeps: 10, duration: 0.1}
domain: {lower: [-0.5, -0.5, 0.0], upper: [0.5, 0.5, 1.0]}
entities:
  - name: jelly
    material: {type: MPM.Elastic, E: 3.0e5, nu: 0.2, rho: 1000}
    morph: {type: Box, lower: [-0.1, -0.1, 0.3], upper: [0.1, 0.1, 0.5]}
"""


def _validate(tmp_path: Path, text: str, *extra: str):
    p = tmp_path / "scene.yaml"
    p.write_text(textwrap.dedent(text))
    r = CliRunner().invoke(cli, ["validate", str(p), *extra])
    return r.exit_code, r.output, str(p)


def test_good_scene_passes(tmp_path):
    code, out, _ = _validate(tmp_path, GOOD)
    assert code == 0, out


@pytest.mark.parametrize(
    "old,new,expect",
    [
        # malformed YAML
        ("  - name: jelly\n", "  - name: [jelly\n", ":6:13: malformed YAML"),
        # wrong type
        ("dt: 2.0e-3", "dt: fast", ":2:19: sim.dt: expected a number (got 'fast')"),
        # out of range
        ("nu: 0.2", "nu: 0.5", ":6:49: entities.0.material.nu: must be < 0.5 (got 0.5)"),
        ("E: 3.0e5", "E: -3.0e5", ":6:38: entities.0.material.E: must be > 0"),
        ("dt: 2.0e-3", "dt: -1.0e-3", ":2:19: sim.dt: must be > 0"),
        (
            "upper: [0.1, 0.1, 0.5]",
            "upper: [0.1, -0.2, 0.5]",
            ":7:12: entities.0.morph: lower must be < upper",
        ),
        ("upper: [0.5, 0.5, 1.0]}", "upper: [0.5, -0.5, 1.0]}", "domain.upper: lower must be < upper"),
        # unknown keys, with a suggestion
        ("substeps: 10", "substep: 10", ":2:27: sim.substep: unknown key (did you mean 'substeps'?)"),
        ("rho: 1000}", "rho: 1000, young: 3}", "entities.0.material.young: unknown key"),
        # unknown material and morph types
        (
            "type: MPM.Elastic",
            "type: MPM.Elastik",
            ":6:22: entities.0.material.type: unknown material type 'MPM.Elastik'",
        ),
        ("type: Box", "type: Cube", ":7:19: entities.0.morph.type: unknown type 'Cube'"),
        # entity outside the domain
        (
            "upper: [0.1, 0.1, 0.5]",
            "upper: [0.1, 0.1, 1.5]",
            ":7:12: entities.0.morph: entity 'jelly' extends outside the domain along z",
        ),
        # missing mesh file
        (
            "morph: {type: Box, lower: [-0.1, -0.1, 0.3], upper: [0.1, 0.1, 0.5]}",
            "morph: {type: Mesh, file: no.obj}",
            ":7:31: entities.0.morph.file: mesh file not found",
        ),
        # too large for memory: estimated before allocating
        (
            "duration: 0.1}",
            "duration: 0.1}\nsolvers: {mpm: {grid_density: 4000, particle_size: 0.0005}}",
            "scene too large",
        ),
    ],
)
def test_bad_input(tmp_path, old, new, expect):
    assert old in GOOD
    code, out, path = _validate(tmp_path, GOOD.replace(old, new))
    assert code == 65, out
    assert f"{path}{expect}" in out or expect in out, out
    assert "Traceback" not in out


def test_duplicate_names_and_all_errors_at_once(tmp_path):
    text = GOOD + GOOD.split("entities:\n")[1].replace("nu: 0.2", "nu: 0.7")
    text = text.replace("dt: 2.0e-3", "dtt: 2.0e-3")
    code, out, path = _validate(tmp_path, text)
    assert code == 65
    lines = out.strip().splitlines()
    assert f"{path}:2:15: sim.dtt: unknown key (did you mean 'dt'?)" in lines
    assert any(l.startswith(f"{path}:9:49: entities.1.material.nu: must be < 0.5") for l in lines), out
    # the duplicate is a semantic check, done once the schema passes; fix the others and it shows
    code, out, path = _validate(tmp_path, text.replace("nu: 0.7", "nu: 0.2").replace("dtt", "dt"))
    assert code == 65
    assert f"{path}:8:11: entities.1.name: duplicate entity name 'jelly'" in out


def test_set_overrides_are_validated(tmp_path):
    code, out, _ = _validate(tmp_path, GOOD, "--set", "sim.dtt=1e-3")
    assert code == 65
    assert "--set sim.dtt=1e-3: sim.dtt: unknown key (did you mean 'dt'?)" in out
    code, out, _ = _validate(tmp_path, GOOD, "--set", "entities.0.material.E=1e6", "--set", "sim.dt=1e-3")
    assert code == 0, out
    code, out, _ = _validate(tmp_path, GOOD, "--set", "entities.3.name=x")
    assert code == 65 and "index 3 out of range" in out


def test_yaml12_floats(tmp_path):
    # PyYAML's YAML 1.1 reads 1e5 as a string; scenes read it as the number it is
    code, out, _ = _validate(tmp_path, GOOD.replace("E: 3.0e5", "E: 3e5").replace("dt: 2.0e-3", "dt: 2e-3"))
    assert code == 0, out


def test_missing_file_and_non_mapping(tmp_path):
    r = CliRunner().invoke(cli, ["validate", str(tmp_path / "nope.yaml")])
    assert r.exit_code == 65 and "file not found" in r.output
    code, out, path = _validate(tmp_path, "- 1\n- 2\n")
    assert code == 65 and f"{path}:1:1" in out


def test_validate_never_imports_taichi(tmp_path):
    # how fast it answers is a benchmark (benchmarks/timings.py), not a test
    p = tmp_path / "scene.yaml"
    p.write_text(GOOD)
    code = (
        "import sys; from simcli.cli import cli\n"
        "try:\n    cli(['validate', sys.argv[1]])\nexcept SystemExit as e:\n    rc = e.code\n"
        "print(rc, 'taichi' in sys.modules)"
    )
    r = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, timeout=60)
    rc, imported = r.stdout.split()
    assert rc == "0" and imported == "False", r.stderr


def test_example_configs_validate():
    root = Path(__file__).resolve().parents[2] / "configs"
    files = sorted(
        f for f in root.rglob("*.yaml") if not f.name.endswith(".case.yaml") and "sweeps" not in f.parts
    )
    assert files
    for f in files:
        r = CliRunner().invoke(cli, ["validate", "-q", str(f)])
        assert r.exit_code == 0, (f, r.output)
        assert f.read_text().startswith("# yaml-language-server: $schema="), f


def test_sph_scene_too_large_names_the_sph_setting(tmp_path):
    """An SPH scene too large for memory: the error names solvers.sph.particle_size and counts boundary
    particles
    and neighbour-grid cells, not MPM's grid."""
    text = """version: 1
sim: {dim: 3, dt: 1.0e-3, substeps: 1, duration: 0.01}
domain: {lower: [0, 0, 0], upper: [1, 1, 1]}
solvers: {sph: {particle_size: 0.0005}}
entities:
  - name: water
    material: {type: SPH.Liquid}
    morph: {type: Box, lower: [0, 0, 0], upper: [1, 1, 0.5]}
"""
    code, out, _ = _validate(tmp_path, text)
    assert code == 65, out
    assert "solvers.sph.particle_size: scene too large" in out and "boundary particles" in out, out
    assert "mpm" not in out


def test_dfsph_cg_rejects_two_rest_densities(tmp_path):
    """DFSPH's conjugate-gradient solve (clamp_pressure: false) needs one rest density: a scene error that
    says what to change, from `simcli validate` already, not a wrong answer."""
    text = """version: 1
sim: {dim: 2, dt: 1.0e-3, substeps: 1, duration: 0.01}
domain: {lower: [0, 0], upper: [1, 1]}
solvers: {sph: {particle_size: 0.01, pressure_solver: DFSPH, clamp_pressure: false}}
entities:
  - name: a
    material: {type: SPH.Liquid, rho: 1000}
    morph: {type: Box, lower: [0.35, 0.4], upper: [0.5, 0.6]}
  - name: b
    material: {type: SPH.Liquid, rho: 500}
    morph: {type: Box, lower: [0.5, 0.4], upper: [0.65, 0.6]}
"""
    code, out, _ = _validate(tmp_path, text)
    assert code == 65, out
    assert "solvers.sph.clamp_pressure" in out and "clamp_pressure: true" in out, out
