"""Sweep files: expansion (grid x zip), run names, and errors with file:line:col."""

from __future__ import annotations

import math
import re

import pytest
from click.testing import CliRunner

from simcli.cli import cli
from simcli.errors import SceneError
from simcli.scene.overrides import parse_set
from simcli.sweep.model import (
    compact_number,
    index_ranges,
    load_run_scene,
    load_sweep,
    parse_indices,
    set_value_text,
    validate_runs,
)

SPEC_EXAMPLE = """\
version: 1
base: tiny.yaml
name: "E{entities.0.material.E}_dt{sim.dt}"
grid:
  entities.0.material.E: [1.0e5, 1.0e6]
  sim.dt: [1.0e-3, 5.0e-4]
zip:
  solvers.mpm.grid_density: [32, 64]
  solvers.mpm.particle_size: [0.02, 0.01]
output: out/jelly_sweep
"""


def _errors(path) -> list[str]:
    with pytest.raises(SceneError) as e:
        load_sweep(path)
    return e.value.lines


def test_grid_times_zip_expansion_order(make_sweep):
    ls = load_sweep(
        make_sweep(
            SPEC_EXAMPLE.replace(
                'name: "E{entities.0.material.E}_dt{sim.dt}"',
                'name: "E{entities.0.material.E}_dt{sim.dt}_g{solvers.mpm.grid_density}"',
            )
        )
    )
    assert len(ls.runs) == 2 * 2 * 2
    got = [
        (
            r.params["entities.0.material.E"],
            r.params["sim.dt"],
            r.params["solvers.mpm.grid_density"],
            r.params["solvers.mpm.particle_size"],
        )
        for r in ls.runs
    ]
    # first grid key slowest, the zipped lists the fastest axis, zipped items stay together
    assert got == [
        (1e5, 1e-3, 32, 0.02),
        (1e5, 1e-3, 64, 0.01),
        (1e5, 5e-4, 32, 0.02),
        (1e5, 5e-4, 64, 0.01),
        (1e6, 1e-3, 32, 0.02),
        (1e6, 1e-3, 64, 0.01),
        (1e6, 5e-4, 32, 0.02),
        (1e6, 5e-4, 64, 0.01),
    ]
    assert [r.index for r in ls.runs] == list(range(8))
    assert ls.runs[1].name == "E1e5_dt1e-3_g64"
    assert ls.runs[1].set_args() == [
        "entities.0.material.E=100000.0",
        "sim.dt=0.001",
        "solvers.mpm.grid_density=64",
        "solvers.mpm.particle_size=0.01",
    ]
    assert str(ls.output_dir) == "out/jelly_sweep"
    assert ls.run_dir(ls.runs[0]).as_posix() == "out/jelly_sweep/E1e5_dt1e-3_g32"
    # each value remembers where it was written in the sweep file
    assert ls.runs[2].sources["sim.dt"].endswith("sweep.yaml:6:20")


def test_spec_example_needs_the_zip_in_the_name(make_sweep):
    # the example's template leaves out the zipped keys: runs 0 and 1 would share a folder
    lines = _errors(make_sweep(SPEC_EXAMPLE))
    assert any(
        re.search(r"sweep\.yaml:3:7: name: runs 0 and 1 both get the name 'E1e5_dt1e-3'", ln) for ln in lines
    ), lines


def test_grid_only_zip_only_and_nothing(make_sweep):
    ls = load_sweep(make_sweep("base: tiny.yaml\ngrid: {sim.dt: [1.0e-3, 2.0e-3, 4.0e-3]}\n"))
    assert [r.params for r in ls.runs] == [{"sim.dt": 1e-3}, {"sim.dt": 2e-3}, {"sim.dt": 4e-3}]
    assert [r.name for r in ls.runs] == ["0", "1", "2"]  # default name: the run index
    ls = load_sweep(make_sweep("base: tiny.yaml\nzip: {sim.dt: [1.0e-3, 2.0e-3], sim.steps: [20, 10]}\n"))
    assert [r.params for r in ls.runs] == [
        {"sim.dt": 1e-3, "sim.steps": 20},
        {"sim.dt": 2e-3, "sim.steps": 10},
    ]
    ls = load_sweep(make_sweep("base: tiny.yaml\n"))
    assert len(ls.runs) == 1 and ls.runs[0].params == {} and ls.runs[0].name == "0"
    assert str(ls.output_dir) == "out/sweep"  # default: out/<sweep file name>


def test_default_names_are_zero_padded(make_sweep):
    ls = load_sweep(make_sweep("base: tiny.yaml\ngrid: {sim.seed: [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]}\n"))
    assert [r.name for r in ls.runs][:3] == ["00", "01", "02"] and ls.runs[-1].name == "11"


def test_name_templates(make_sweep):
    ls = load_sweep(
        make_sweep("""\
        base: tiny.yaml
        name: "{index:03d}_E{entities.0.material.E:.1e}_{entities.0.name}_d{sim.dim}_g{sim.gravity}"
        grid:
          entities.0.material.E: [12345.0]
          sim.gravity: [[0, -9.81], [0.5, -1]]
        """)
    )
    # format specs, base-scene keys (entities.0.name, sim.dim), lists; unsafe characters become _
    assert [r.name for r in ls.runs] == ["000_E1.2e+04_box_d2_g0_-9.81", "001_E1.2e+04_box_d2_g0.5_-1"]
    ls = load_sweep(make_sweep('base: tiny.yaml\nname: "run {sim.dt}/x"\ngrid: {sim.dt: [0.001]}\n'))
    assert ls.runs[0].name == "run_1e-3_x"


@pytest.mark.parametrize(
    "v,text",
    [
        (1e5, "1e5"),
        (1e6, "1e6"),
        (2.5e5, "2.5e5"),
        (1e-3, "1e-3"),
        (0.01, "0.01"),
        (5e-4, "5e-4"),
        (64.0, "64"),
        (1.5, "1.5"),
        (0.3, "0.3"),
        (0.0, "0"),
        (-3e-3, "-3e-3"),
        (123456.789, "123456.789"),
    ],
)
def test_compact_numbers_are_exact_and_short(v, text):
    assert compact_number(v) == text
    assert float(text) == v


@pytest.mark.parametrize(
    "v", [1e5, 1e-5, 0.1 + 0.2, 3, True, None, "MPM.Elastic", "1e5", [0, -9.81], {"a": 1}, math.inf]
)
def test_set_values_parse_back_identically(v):
    _, back = parse_set(f"a.b={set_value_text(v)}")
    assert back == v and type(back) is type(v)


def test_index_lists():
    assert index_ranges([0, 1, 2, 5, 7, 8]) == "0-2,5,7-8"
    assert parse_indices("0-2,5", 8) == [0, 1, 2, 5]
    with pytest.raises(ValueError, match="does not exist"):
        parse_indices("3-9", 8)
    with pytest.raises(ValueError):
        parse_indices("x", 8)


@pytest.mark.parametrize(
    "text,expect",
    [
        (
            "base: tiny.yaml\ngird: {sim.dt: [1]}\n",
            r"sweep\.yaml:2:1: gird: unknown key \(did you mean 'grid'\?\)",
        ),
        (
            "base: tiny.yaml\ngrid: {sim.dt: 0.001}\n",
            r"sweep\.yaml:2:16: grid\.sim\.dt: expected a list of values",
        ),
        (
            "base: tiny.yaml\ngrid: {sim.dt: []}\n",
            r"sweep\.yaml:2:16: grid\.sim\.dt: must list at least one value",
        ),
        ("base: tiny.yaml\ngrid: {sim..dt: [1]}\n", r"sweep\.yaml:2:8: grid\.sim\.\.dt: bad key path"),
        (
            "base: tiny.yaml\nzip:\n  sim.dt: [1, 2]\n  sim.seed: [1, 2, 3]\n",
            r"sweep\.yaml:2:1: zip: the lists must have equal lengths \(sim\.dt: 2, sim\.seed: 3\)",
        ),
        (
            "base: tiny.yaml\ngrid: {sim.dt: [1]}\nzip: {sim.dt: [2]}\n",
            r"sweep\.yaml:3:7: zip\.sim\.dt: also varied in grid",
        ),
        (
            "base: tiny.yaml\ngrid: {sim: [{}], sim.dt: [1]}\n",
            r"sweep\.yaml:2:19: grid\.sim\.dt: overlaps grid\.sim",
        ),
        ("base: nothere.yaml\n", r"sweep\.yaml:1:7: base: scene file not found: .*nothere\.yaml"),
        ("grid: {sim.dt: [1]}\n", r"sweep\.yaml:1:1: base: required key missing"),
        ("base: tiny.yaml\nversion: 2\n", r"sweep\.yaml:2:10: version: expected 1"),
        (
            "base: tiny.yaml\ngrid: {entities.3.material.E: [1]}\n",
            r"sweep\.yaml:2:8: grid\.entities\.3\.material\.E: cannot set it in .*tiny\.yaml: "
            r"index 3 out of range",
        ),
        (
            'base: tiny.yaml\nname: "E{entities.0.material.EE}"\ngrid: {entities.0.material.E: [1, 2]}\n',
            (
                r"sweep\.yaml:2:7: name: \{entities\.0\.material\.EE\} is neither a varied key nor a key of "
                r"the base scene \(did you mean 'entities\.0\.material\.E'\?\)"
            ),
        ),
        ('base: tiny.yaml\nname: "E{oops"\n', r"sweep\.yaml:2:7: name: bad template"),
        ("base: tiny.yaml\ngrid: {sim.dt: [1]}\n  bad: [\n", r"sweep\.yaml:\d+:\d+: malformed YAML"),
    ],
)
def test_bad_sweep_files_name_file_line_col(make_sweep, text, expect):
    lines = _errors(make_sweep(text))
    assert any(re.search(expect, ln) for ln in lines), lines


def test_every_problem_is_reported_at_once(make_sweep):
    lines = _errors(make_sweep("base: tiny.yaml\ngird: {}\noutptu: x\ngrid: {sim.dt: 3}\n"))
    assert len(lines) == 3, lines
    assert [ln.split(":")[1] for ln in lines] == ["2", "3", "4"]  # in file order


def test_validate_reports_a_bad_value_where_the_sweep_sets_it(make_sweep):
    p = make_sweep("""\
        base: tiny.yaml
        name: "nu{entities.0.material.nu}_dt{sim.dt}"
        grid:
          entities.0.material.nu: [0.3, 0.7]
          sim.dt: [1.0e-3, -1.0]
        """)
    ls = load_sweep(p)
    lines = validate_runs(ls)
    assert f"{p}:4:33: entities.0.material.nu: must be < 0.5 (got 0.7) [runs 2-3]" in lines, lines
    assert f"{p}:5:20: sim.dt: must be > 0.0 (got -1.0) [runs 1,3]" in lines, lines
    assert len(lines) == 2
    # a run that is fine loads as a scene with the values applied
    s = load_run_scene(ls, ls.runs[0]).scene
    assert s.entities[0].material.nu == 0.3 and s.sim.dt == 1e-3


def test_validate_reports_base_scene_errors_once(make_sweep):
    from tests.sweep.conftest import TINY

    p = make_sweep(
        "base: tiny.yaml\ngrid: {sim.dt: [1.0e-3, 2.0e-3]}\n",
        scene=TINY.read_text().replace("nu: 0.2", "nu: 0.6"),
    )
    lines = validate_runs(load_sweep(p))
    assert len(lines) == 1 and re.search(
        r"tiny\.yaml:9:\d+: entities\.0\.material\.nu: must be < 0\.5", lines[0]
    ), lines


def test_cli_expand_validate_and_exit_codes(make_sweep, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    good = make_sweep('base: tiny.yaml\nname: "dt{sim.dt}"\ngrid: {sim.dt: [1.0e-3, 2.0e-3]}\n')
    r = CliRunner().invoke(cli, ["sweep", "expand", str(good)])
    assert r.exit_code == 0, r.output
    assert re.search(r"^0\s+dt1e-3\s+1e-3$", r.stdout, re.MULTILINE) and re.search(
        r"^1\s+dt2e-3\s+2e-3$", r.stdout, re.MULTILINE
    )
    r = CliRunner().invoke(cli, ["sweep", "expand", str(good), "--json"])
    import json

    data = json.loads(r.stdout)
    assert data[1]["overrides"] == {"sim.dt": 0.002} and data[1]["out"] == "out/sweep/dt2e-3"
    assert CliRunner().invoke(cli, ["sweep", "validate", str(good)]).exit_code == 0
    bad = make_sweep("base: tiny.yaml\ngrid: {entities.0.material.nu: [0.9]}\n", name="bad.yaml")
    r = CliRunner().invoke(cli, ["sweep", "validate", str(bad)])
    assert r.exit_code == 65 and "bad.yaml:2:33: entities.0.material.nu: must be < 0.5 (got 0.9)" in r.stderr
    r = CliRunner().invoke(
        cli, ["sweep", "expand", str(make_sweep("base: tiny.yaml\ngird: {}\n", name="b2.yaml"))]
    )
    assert r.exit_code == 65 and "b2.yaml:2:1: gird: unknown key (did you mean 'grid'?)" in r.stderr
    r = CliRunner().invoke(cli, ["sweep", "expand", str(tmp_path / "missing.yaml")])
    assert r.exit_code == 65 and "missing.yaml: file not found" in r.stderr


def test_example_sweep_in_configs_is_valid():
    from tests.sweep.conftest import ROOT

    for p in sorted((ROOT / "configs" / "sweeps").glob("*.yaml")):
        if "base" not in p.read_text():
            continue  # a scene file used as a base
        ls = load_sweep(p)
        assert validate_runs(ls) == [], p
        assert len(ls.runs) >= 2


def test_committed_sweep_schema_is_current(tmp_path):
    from simcli.sweep.model import sweep_schema_text
    from simcli.sweep.schema import write_schemas
    from tests.sweep.conftest import ROOT

    committed = (ROOT / "schemas" / "sweep.schema.json").read_text()
    assert committed == sweep_schema_text(), (
        "schemas/sweep.schema.json is stale: run `simcli schema -o schemas`"
    )
    written = write_schemas(tmp_path)
    assert (tmp_path / "sweep.schema.json") in written
    assert (tmp_path / "sweep.schema.json").read_text() == committed


def test_sweep_files_are_recognised(make_sweep):
    from simcli.sweep.model import looks_like_sweep
    from tests.sweep.conftest import TINY

    assert looks_like_sweep(make_sweep("base: tiny.yaml\n"))
    assert not looks_like_sweep(TINY)
