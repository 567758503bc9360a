"""The coupling key and the coupling phase's choice of pairs (no Taichi run; the physics is in simcli verify's
coupling_* cases, docs/COUPLING.md)."""

from __future__ import annotations

import textwrap
from pathlib import Path

from click.testing import CliRunner

from simcli.cli import cli
from simcli.coupling import IMPLEMENTED, PAIRS, make_coupler
from simcli.scene.coupling import IMPLEMENTED_PAIRS
from simcli.scene.loader import load_scene

SCENE = """\
version: 1
sim: {dim: 2, dt: 2.0e-3, substeps: 10, duration: 0.1}
domain: {lower: [0.0, 0.0], upper: [0.4, 0.3]}
entities:
  - name: water
    material: {type: SPH.Liquid, rho: 1000}
    morph: {type: Box, lower: [0.0, 0.0], upper: [0.4, 0.1]}
  - name: block
    material: {type: MPM.Elastic, E: 1.0e5, nu: 0.3, rho: 500}
    morph: {type: Box, lower: [0.15, 0.12], upper: [0.25, 0.2]}
"""


class _Fake:
    def __init__(self, family):
        self.family = family
        self.store_node_mass = False
        self.dim = 3


def _scene(tmp_path: Path, extra: str = ""):
    p = tmp_path / "scene.yaml"
    p.write_text(SCENE + textwrap.dedent(extra))
    return p


def test_pairs_implemented_agree():
    assert set(IMPLEMENTED) == set(IMPLEMENTED_PAIRS)
    assert {k for k, _, _ in PAIRS} >= set(IMPLEMENTED)


def test_pair_on_by_default_and_off_with_false(tmp_path):
    solvers = [_Fake("sph"), _Fake("mpm")]
    on = make_coupler(load_scene(_scene(tmp_path)).scene, solvers)
    assert on is not None and on.names == ["mpm_sph"]
    assert solvers[1].store_node_mass  # the MPM grid keeps its node masses for the coupling phase
    solvers = [_Fake("sph"), _Fake("mpm")]
    off = make_coupler(load_scene(_scene(tmp_path, "coupling: {mpm_sph: false}\n")).scene, solvers)
    assert off is None  # nothing coupled: the runner steps the solvers exactly as before
    assert not solvers[1].store_node_mass


def test_single_family_has_no_coupler(tmp_path):
    assert make_coupler(load_scene(_scene(tmp_path)).scene, [_Fake("mpm")]) is None


def test_every_pair_is_implemented_and_none_warns(tmp_path):
    assert set(IMPLEMENTED) == {k for k, _, _ in PAIRS}
    scene = load_scene(_scene(tmp_path)).scene
    for key, a, b in PAIRS:
        said = []
        c = make_coupler(scene, [_Fake(a), _Fake(b)], said.append)
        assert c is not None and c.names == [key], key
        assert said == []  # "do not interact yet" is gone for every pair
    off = load_scene(_scene(tmp_path, "coupling: {sph_fem: false}\n")).scene
    assert make_coupler(off, [_Fake("sph"), _Fake("fem")]) is None  # false: they pass through each other


def test_key_for_absent_pair_is_a_warning_with_location(tmp_path):
    p = _scene(tmp_path, "coupling: {mpm_sph: true, mpm_pbd: false}\n")
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 0, r.output  # a warning, not an error
    lines = [ln for ln in r.output.splitlines() if "coupling.mpm_pbd" in ln]
    assert len(lines) == 1, r.output
    assert lines[0].startswith(f"{p}:{SCENE.count(chr(10)) + 1}:")  # file:line:col of the key
    assert "warning" in lines[0] and "no PBD entity" in lines[0]
    assert "coupling.mpm_sph" not in r.output  # a pair that is present says nothing


def test_unknown_pair_key_is_an_error(tmp_path):
    r = CliRunner().invoke(cli, ["validate", str(_scene(tmp_path, "coupling: {mpm_rigid: true}\n"))])
    assert r.exit_code == 65
    assert "coupling.mpm_rigid" in r.output


def test_overlap_warning_says_coupled_families_push_apart(tmp_path):
    text = SCENE.replace("lower: [0.15, 0.12]", "lower: [0.15, 0.08]")
    p = tmp_path / "s.yaml"
    p.write_text(text)
    out = CliRunner().invoke(cli, ["validate", str(p)]).output
    assert "push each other out" in out
    p.write_text(text + "coupling: {mpm_sph: false}\n")
    out = CliRunner().invoke(cli, ["validate", str(p)]).output
    assert "do not interact" in out


def test_a_family_no_pair_covers_warns_that_it_passes_through(tmp_path):
    """FEM.Cloth beside MPM sand: no coupling pair covers FEM.Cloth, so validate says, at the cloth's line,
    that the two pass through each other (not a silent pass-through)."""
    p = tmp_path / "cloth_sand.yaml"
    p.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, substeps: auto, duration: 0.02}
            domain: {lower: [-1, -1, 0], upper: [1, 1, 1.5]}
            entities:
              - name: cloth
                material: {type: FEM.Cloth, E: 1.0e6, nu: 0.3, rho: 400, thickness: 5.0e-4}
                morph: {type: Rectangle, center: [0, 0, 0.6], size: [1.0, 1.0], resolution: 8}
              - name: sand
                material: {type: MPM.Sand, E: 1.0e5, nu: 0.3, rho: 1600}
                morph: {type: Box, center: [0, 0, 0.1], size: [0.4, 0.4, 0.1]}
            """
        )
    )
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 0, r.output
    line = next(x for x in r.output.splitlines() if "FEM.Cloth" in x)
    assert line.startswith(f"{p}:5:") and "warning" in line and "MPM" in line and "pass through" in line
