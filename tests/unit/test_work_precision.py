"""Work-precision studies (simcli/verify/variants.py, benchmarks/work_precision.py): variant overrides,
the CSV merge that adds an option to a published study, the doc table markers. No simulation runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from simcli.errors import SceneError
from simcli.verify import variants as wp
from simcli.verify.cases import load_case
from simcli.verify.run import level_overrides

ROOT = Path(__file__).resolve().parents[2]


def _case(tmp_path):
    (tmp_path / "s.yaml").write_text(
        "version: 1\nname: s\nsim: {dim: 2, dt: 1.0e-3, duration: 0.01}\n"
        "domain: {lower: [0, 0], upper: [1, 1]}\nsolvers:\n  mpm: {grid_density: 20}\n"
        "entities:\n  - name: b\n    material: {type: MPM.Elastic, E: 1.0e4, nu: 0.3, rho: 1000}\n"
        "    morph: {type: Box, lower: [0.4, 0.4], upper: [0.6, 0.6]}\n"
    )
    (tmp_path / "c.case.yaml").write_text(
        "scene: s.yaml\nmeasure: {quantity: com}\nreference: {value: 0.5}\ntolerance: 0.1\n"
        "overrides: {solvers.mpm.transfer: flip, solvers.mpm.flip_ratio: 1.0}\n"
        "refine: {solvers.mpm.grid_density: 2}\n"
    )
    return load_case(tmp_path / "c.case.yaml")


def test_variant_spec_is_a_label_and_typed_overrides():
    v = wp.parse_variant("FLIP 0.99: solvers.mpm.transfer=flip solvers.mpm.flip_ratio=0.99")
    assert v.label == "FLIP 0.99"
    assert v.overrides == {"solvers.mpm.transfer": "flip", "solvers.mpm.flip_ratio": 0.99}
    assert wp.parse_variant("tet10: solvers.fem.element=tet10").overrides == {"solvers.fem.element": "tet10"}
    assert wp.parse_variant("as written").overrides == {}
    assert wp.parse_variant("x: 'entities.0.morph.lower=[0.1, 0.2]'").overrides == {
        "entities.0.morph.lower": [0.1, 0.2]
    }
    with pytest.raises(SceneError, match="no label"):
        wp.parse_variant(": sim.dt=1")
    with pytest.raises(SceneError, match="KEY=VALUE"):
        wp.parse_variant("a: sim.dt")


def test_variant_overrides_win_over_the_study_and_the_case_and_reach_the_run(tmp_path):
    case = _case(tmp_path)
    v = wp.Variant("APIC", {"solvers.mpm.transfer": "apic"})
    c = wp.variant_case(case, v, {"sim.dt": 5.0e-4}, {"solvers.mpm.grid_density": 3})
    assert c.name == "c [APIC]"
    assert c.overrides == {"solvers.mpm.transfer": "apic", "solvers.mpm.flip_ratio": 1.0, "sim.dt": 5.0e-4}
    assert c.refine == {"solvers.mpm.grid_density": 3}
    assert case.overrides["solvers.mpm.transfer"] == "flip" and case.name == "c"  # the case is untouched
    sets = level_overrides(c, 1)
    assert 'solvers.mpm.transfer="apic"' in sets and "sim.dt=0.0005" in sets
    vals = wp.resolved_values(c.scene_path, sets, ["solvers.mpm.grid_density", "solvers.mpm.transfer"])
    assert vals["solvers.mpm.grid_density"] == pytest.approx(60)
    assert vals["solvers.mpm.transfer"] == "apic"


def _row(variant, level, error):
    return dict(
        study="s", variant=variant, level=level, resolution=f"r={level}", x=10.0 * 2**level, error=error,
        order=None, stepping_s=1.0 + level, wall_s=3.0, particles=100, substeps_total=10, exit_code=0,
        overrides="", message="",
    )  # fmt: skip


def test_merge_replaces_rerun_variants_and_keeps_the_others_through_the_csv(tmp_path):
    old = [_row("tet4", 0, 0.3), _row("tet4", 1, 0.1), _row("tet10", 0, 0.9)]
    path = tmp_path / "d" / "s.csv"
    wp.write_rows(old, path)
    back = wp.read_rows(path)
    assert [(r["variant"], r["level"], r["error"]) for r in back] == [
        ("tet4", 0, 0.3),
        ("tet4", 1, 0.1),
        ("tet10", 0, 0.9),
    ]
    assert back[0]["order"] is None and back[0]["particles"] == 100 and back[1]["x"] == 20.0
    new = [_row("tet10", 1, 0.002), _row("tet10", 0, 0.01), _row("midpoint", 0, 1e-5)]
    merged = wp.merge_rows(back, new)
    assert [(r["variant"], r["level"], r["error"]) for r in merged] == [
        ("tet4", 0, 0.3),
        ("tet4", 1, 0.1),
        ("tet10", 0, 0.01),
        ("tet10", 1, 0.002),
        ("midpoint", 0, 1e-5),
    ]
    assert wp.read_rows(tmp_path / "missing.csv") == []


def test_table_goes_between_the_markers_only(tmp_path):
    doc = tmp_path / "X.md"
    doc.write_text("a\n<!-- wp:s -->\nold\n<!-- /wp:s -->\nb\n")
    st = wp.Study(name="s", case="c", error_label="|w/w0 - 1| [-]")
    table = wp.markdown([_row("tet4", 0, 0.25), {**_row("tet10", 0, None), "exit_code": 1}], st)
    assert "| tet4 | 0 | r=0 | 0.25 |" in table and "run failed (1)" in table
    assert "\\|w/w0 - 1\\| [-]" in table.splitlines()[0] and "100 particles" in table
    assert wp.size_of({"fem": {"vertices": 1025, "tets": 3840}}) == "1025 vertices / 3840 tets"
    assert wp.size_of({"mpm": {"particles": 416, "grid_cells": 3025}}) == "416 particles"
    assert wp.update_doc(doc, "s", table)
    text = doc.read_text()
    assert text.startswith("a\n<!-- wp:s -->\n| variant |") and text.endswith("<!-- /wp:s -->\nb\n")
    assert "old" not in text
    assert not wp.update_doc(doc, "other", table)


def test_shipped_studies_name_existing_cases_and_known_keys():
    studies = wp.load_studies(ROOT / "benchmarks" / "work_precision.yaml")
    names = {p.name.removesuffix(".case.yaml") for p in (ROOT / "configs" / "validation").glob("*.case.yaml")}
    assert studies and all(s.case in names for s in studies.values())
    assert all(s.variants and s.plot and s.csv for s in studies.values())


def test_unknown_study_key_is_an_error(tmp_path):
    f = tmp_path / "w.yaml"
    f.write_text("s: {case: c, variantz: {}}\n")
    with pytest.raises(SceneError, match="variantz"):
        wp.load_studies(f)


def test_verify_variant_option_names_one_case_per_variant_and_refuses_a_bad_spec():
    from click.testing import CliRunner

    from simcli.verify.cli import verify

    args = ["mpm_disk_sulsky_flip_energy", "--list"]
    r = CliRunner().invoke(
        verify, args + ["--variant", "APIC: solvers.mpm.transfer=apic", "--variant", "FLIP"]
    )
    assert r.exit_code == 0, r.output
    names = [line.split("\t")[0] for line in r.output.splitlines()]
    assert names == ["mpm_disk_sulsky_flip_energy [APIC]", "mpm_disk_sulsky_flip_energy [FLIP]"]
    r = CliRunner().invoke(verify, args + ["--variant", "APIC: solvers.mpm.transfer"])
    assert r.exit_code == 65 and "KEY=VALUE" in r.output


def test_repetitions_keep_the_fastest_stepping_time_and_flag_differing_errors():
    a = [_row("apic", 0, 0.3), _row("apic", 1, 0.1)]
    b = [{**_row("apic", 0, 0.3), "stepping_s": 0.5}, {**_row("apic", 1, 0.1), "stepping_s": 9.0}]
    c = [_row("apic", 0, 0.3), {**_row("apic", 1, 0.2), "stepping_s": None}]
    rows = wp.fastest_of([a, b, c])
    assert [r["stepping_s"] for r in rows] == [0.5, 2.0]
    assert rows[0]["message"] == "fastest of 3 runs"
    assert "errors differ" in rows[1]["message"] and rows[1]["error"] == 0.1
    assert wp.fastest_of([a]) == a


def test_study_changes_the_measurement_and_scales_its_lengths_with_the_level(tmp_path):
    case = _case(tmp_path)
    st = wp.Study(
        name="s",
        case="c",
        measure_params={"spacing": 0.004, "q": 99},
        refine_params={"spacing": 0.5},
        error={"metric": "nmae"},
    )
    c = wp.study_case(st, case, wp.Variant("APIC", {}))
    assert c.measure.params == {"spacing": 0.004, "q": 99} and c.error.metric == "nmae"
    assert case.measure.params == {} and case.error.metric == "max_rel"
    assert wp.level_case(st, c, 0) is c
    assert wp.level_case(st, c, 2).measure.params == {"spacing": 0.001, "q": 99}
    assert c.measure.params["spacing"] == 0.004


def test_script_lists_the_studies_and_refuses_an_unknown_one(capsys):
    import importlib.util

    spec = importlib.util.spec_from_file_location("work_precision", ROOT / "benchmarks" / "work_precision.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--list"]) == 0
    assert (
        "mpm_transfers_sulsky\tmpm_disk_sulsky_flip_energy\tAPIC, FLIP 0.99, pure FLIP"
        in capsys.readouterr().out
    )
    assert mod.main(["no_such_study"]) == 65
    assert "unknown study no_such_study" in capsys.readouterr().err
    assert mod.main(["mpm_transfers_sulsky", "--variant", ": x=1"]) == 65


def test_a_static_study_counts_the_first_step_that_simcli_times_with_the_compilation(tmp_path):
    st = wp.Study(name="s", case="c", time="first_step")
    assert wp._time_of(st, 0.01, 4.0) == pytest.approx(4.01)
    assert wp._time_of(wp.Study(name="s", case="c"), 0.01, 4.0) == 0.01
    assert (
        wp.time_of_row({"stepping_s": 2.0}) == 2.0
        and wp.time_of_row({"stepping_s": 2.0, "time_s": 5.0}) == 5.0
    )
    assert "first step + stepping [s]" in wp.markdown([{**_row("tet10", 0, 0.02), "time_s": 4.01}], st)
    f = tmp_path / "w.yaml"
    f.write_text("s: {case: c, time: cpu}\n")
    with pytest.raises(SceneError, match="time: one of"):
        wp.load_studies(f)
