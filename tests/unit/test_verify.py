"""The verification machinery: cases as data, references, metrics, refinement, report."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simcli.verify.cases import Case, discover, load_case
from simcli.verify.reference import compute_error, read_table, reference_dir, table_path
from simcli.verify.report import markdown_table
from simcli.verify.run import Result, level_overrides

ROOT = Path(__file__).resolve().parents[2]


def _case(tmp_path, text: str, scene: str = "s.yaml") -> Case:
    (tmp_path / scene).write_text(
        "version: 1\nsim: {dim: 2, substeps: 4}\nsolvers: {mpm: {grid_density: 32}}\n"
    )
    p = tmp_path / "c.case.yaml"
    p.write_text(f"scene: {scene}\n" + text)
    return load_case(p)


def test_discover_finds_every_case_file():
    cases = discover()
    names = {c.name for c in cases}
    assert {"free_fall", "rest_on_floor", "cantilever"} <= names
    assert all(c.scene_path.exists() for c in cases)
    assert any("fast" in c.tags for c in cases)


def test_analytic_reference_and_metrics(tmp_path):
    c = _case(
        tmp_path,
        "measure: {quantity: com}\nreference: {analytic: 'a - b * t', constants: {a: 1, b: 2}}\n"
        "error: {metric: max_abs}\ntolerance: 0.1\n",
    )
    t = np.linspace(0, 1, 11)
    e = compute_error(c, t, 1 - 2 * t + 0.05)
    assert e["error"] == pytest.approx(0.05)


def test_midrange_of_an_oscillation_is_the_static_value(tmp_path):
    c = _case(
        tmp_path,
        "measure: {quantity: com}\nreference: {value: -2.0}\n"
        "error: {metric: midrange_rel, window: [0.5, 2.0]}\ntolerance: 0.01\n",
    )
    t = np.linspace(0, 2, 2001)
    z = -2.0 * (1 - np.cos(2 * math.pi * 1.37 * t))  # released from rest, any period
    assert compute_error(c, t, z)["error"] < 1e-3


def test_period_mean_of_an_oscillation_with_a_higher_mode(tmp_path):
    c = _case(
        tmp_path,
        "measure: {quantity: com}\nreference: {value: -2.0}\n"
        "error: {metric: period_mean_rel, window: [0.0, 0.6]}\ntolerance: 0.01\n",
    )
    t = np.linspace(0, 0.6, 601)
    z = -2.0 * (1 - np.cos(2 * math.pi * t / 0.196)) + 0.1 * np.sin(2 * math.pi * t / 0.031)
    assert compute_error(c, t, z)["error"] < 5e-3


def test_table_reference_shipped_with_simcli(tmp_path):
    tab = read_table(reference_dir() / "martin_moyce_1952_n2_2_front.csv")
    assert tab.shape[1] >= 2 and len(tab) > 5
    c = _case(
        tmp_path,
        "measure: {quantity: percentile}\n"
        "reference: {table: '${REFERENCE}/martin_moyce_1952_n2_2_front.csv'}\n"
        "error: {metric: max_rel}\ntolerance: 0.1\n",
    )
    t = tab[:, 0]  # measured at the table's own times: interpolation is exact
    e = compute_error(c, t, tab[:, 1] * 1.05)
    assert e["error"] == pytest.approx(0.05, rel=1e-6)


def test_nmae_is_the_mean_absolute_error_over_the_reference_maximum(tmp_path):
    c = _case(
        tmp_path,
        "measure: {quantity: com}\nreference: {analytic: 'sin(t)'}\n"
        "error: {metric: nmae, window: [0.0, 3.0]}\ntolerance: 0.1\n",
    )
    t = np.linspace(0, 3, 3001)
    e = compute_error(c, t, np.sin(t) + 0.02 * np.where(t < 1.5, 1.0, -1.0))
    assert e["error"] == pytest.approx(0.02 / 1.0, rel=1e-3)  # max sin over [0, 3] = 1


def test_arrival_time_of_a_jump_against_a_table(tmp_path):
    tab = read_table(reference_dir() / "kleefsman2005_spheric_test2.csv")
    (tmp_path / "ref.csv").write_text("t,p\n" + "\n".join(f"{a},{b}" for a, b in zip(tab[:, 0], tab[:, 1])))
    c = _case(
        tmp_path,
        "measure: {quantity: probe}\nreference: {table: ref.csv}\n"
        "error: {metric: arrival_rel, threshold: 1000.0, window: [0.0, 1.0]}\ntolerance: 0.1\n",
    )
    t_exp = tab[np.argmax(tab[:, 1] >= 1000.0), 0]
    assert 0.38 < t_exp < 0.41  # the MARIN P1 impact
    t = np.linspace(0, 1, 1001)
    p = np.where(t < 0.44, np.nan, 5000.0)  # dry until an impact at 0.44 s
    e = compute_error(c, t, p)
    assert e["measured"] == pytest.approx(0.44, abs=1e-3)
    assert e["error"] == pytest.approx(abs(0.44 - e["reference"]) / e["reference"])
    assert abs(e["reference"] - t_exp) <= 0.0051  # interpolated within the table's 5 ms sample
    never = compute_error(c, t, np.zeros_like(t))
    assert never["error"] == math.inf


def test_arrival_metric_needs_a_threshold(tmp_path):
    from simcli.errors import SceneError

    with pytest.raises(SceneError, match="threshold"):
        _case(
            tmp_path,
            "measure: {quantity: probe}\nreference: {value: 1}\n"
            "error: {metric: arrival_rel}\ntolerance: 0.1\n",
        )


def test_impulse_is_the_window_integral_of_each_series_on_its_own_samples(tmp_path):
    """impulse_rel on the shipped Buchner P1 table: a measurement equal to the (normalised) table has error 0
    whatever its sampling; scaled by 1.3 (NaN where dry counts as 0), error 0.3; a window is required."""
    from simcli.errors import SceneError

    body = (
        "measure: {quantity: probe}\n"
        "reference: {table: '${REFERENCE}/buchner2002_dam_break_2d_p1.csv', scale_t: 'x / 2', "
        "scale_v: 'x * 100'}\n"
    )
    c = _case(tmp_path, body + "error: {metric: impulse_rel, window: [1.1, 1.75]}\ntolerance: 0.2\n")
    tab = read_table(reference_dir() / "buchner2002_dam_break_2d_p1.csv")
    t_ref, p_ref = tab[:, 0] / 2, tab[:, 1] * 100
    t = np.linspace(0.0, 3.6, 72001)  # a fine sampling of the table's piecewise-linear curve
    p = np.interp(t, t_ref, p_ref)
    e = compute_error(c, t, p)
    assert e["error"] < 1e-4 and e["reference"] > 0
    p2 = np.where(t < t_ref[0], np.nan, 1.3 * p)
    assert compute_error(c, t, p2)["error"] == pytest.approx(0.3, rel=1e-3)
    with pytest.raises(SceneError, match="window"):
        _case(tmp_path, body + "error: {metric: impulse_rel}\ntolerance: 0.2\n")


def test_every_case_reads_its_table_from_inside_the_repository():
    """A clone is self-contained: every table a shipped case reads lies in the repository (the
    shipped reference_data/ is package data, so it also ships with a non-editable install), and every
    shipped table names its source in reference_data/README.md."""
    tables = {table_path(c).resolve() for c in discover() if c.reference.table is not None}
    assert tables, "no case reads a table"
    for t in tables:
        assert t.is_file() and t.is_relative_to(ROOT), t
    readme = (reference_dir() / "README.md").read_text()
    for f in sorted(reference_dir().glob("*.csv")):
        assert f"`{f.name}`" in readme, f"{f.name} has no source in reference_data/README.md"
        assert f.read_text().startswith("#"), f"{f.name} does not start with its source"
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert "reference_data/*.csv" in pyproject


def test_table_outside_the_reference_folder_or_missing_is_a_clear_error(tmp_path):
    from simcli.errors import SceneError

    with pytest.raises(SceneError) as e:
        _case(
            tmp_path,
            # the variable of the old layout, spelt in two parts so that no grep for it finds a reader
            "measure: {quantity: com}\nreference: {table: '${" + "SHARED}/reference/x.csv'}\ntolerance: 1\n",
        )
    assert "${REFERENCE}" in e.value.lines[0] and ":3:" in e.value.lines[0]
    with pytest.raises(SceneError) as e:
        _case(
            tmp_path, "measure: {quantity: com}\nreference: {table: '${REFERENCE}/nope.csv'}\ntolerance: 1\n"
        )
    assert "c.case.yaml:3:20: reference.table: file not found" in e.value.lines[0]


def test_refinement_levels_scale_the_keys(tmp_path):
    c = _case(
        tmp_path,
        "measure: {quantity: com}\nreference: {value: 0}\ntolerance: 1\n"
        "refine: {solvers.mpm.grid_density: 2, sim.substeps: 2}\n",
    )
    assert level_overrides(c, 0) == []
    assert level_overrides(c, 2) == ["solvers.mpm.grid_density=128.0", "sim.substeps=16"]


def test_bad_case_file_is_reported_with_position(tmp_path):
    from simcli.errors import SceneError

    with pytest.raises(SceneError) as e:
        _case(tmp_path, "measure: {quantity: com}\nreference: {value: 0}\ntolerance: -1\n")
    assert ":4:12: tolerance" in e.value.lines[0]


def test_report_table_has_every_result():
    rs = [
        Result("a", 0, "gd=32", 0.1, 0.05, None, 1.0, 0.5, 0.2, 100, 1e6, 10, 0),
        Result("a", 1, "gd=64", 0.02, 0.05, True, 2.0, 1.5, 0.2, 800, 1e6, 20, 0, order=2.32),
    ]
    md = markdown_table(rs)
    assert "| a | 1 | gd=64 | 0.02 | 0.05 | pass | 2.32 |" in md and "(coarser level)" in md


def test_a_measurement_is_shown_not_judged_but_a_failed_run_still_fails():
    ok = Result("m", 0, "-", 0.4, 0.05, True, 1.0, 0.5, 0.2, 100, 1e6, 10, 0, kind="measurement")
    bad = Result("m", 0, "-", None, 0.05, False, 1.0, None, None, None, None, None, 70, kind="measurement")
    val = Result("v", 0, "-", 0.4, 0.05, False, 1.0, 0.5, 0.2, 100, 1e6, 10, 0)
    assert (ok.status, bad.status, val.status) == ("measured", "FAIL", "FAIL")
    md = markdown_table([ok, bad, val])
    assert "| m | 0 | - | 0.4 | 0.05 | measured |" in md and "| v | 0 | - | 0.4 | 0.05 | FAIL |" in md


@pytest.mark.timeout(600)
def test_verify_exits_0_on_a_measurement_beyond_its_band_and_1_on_a_failed_validation(tmp_path):
    """`simcli verify --root`: a measurement case whose error exceeds its band reads "measured" (exit 0);
    the same scene as a validation case with that tolerance FAILs (exit 1)."""
    root = tmp_path / "cases"
    root.mkdir()
    (root / "fall.yaml").write_text(
        "version: 1\nsim: {dim: 2, dt: 5.0e-3, substeps: 4, duration: 0.05}\n"
        "domain: {lower: [0, 0], upper: [1, 1]}\nsolvers: {mpm: {grid_density: 32}}\n"
        "entities:\n  - name: b\n    material: {type: MPM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000}\n"
        "    morph: {type: Box, center: [0.5, 0.7], size: [0.1, 0.1]}\noutput: {every: 5, formats: [hdf5]}\n"
    )
    case = (
        "scene: fall.yaml\nmeasure: {quantity: com, entity: b, axis: 1}\n"
        "reference: {value: 0.5}\nerror: {metric: final_abs}\ntolerance: 0.01\n"
    )
    (root / "fall_m.case.yaml").write_text(case + "kind: measurement\n")
    (root / "fall_v.case.yaml").write_text(case)

    def verify(name):
        out = tmp_path / name
        r = subprocess.run(
            [sys.executable, "-m", "simcli", "verify", name, "--root", str(root), "-o", str(out)],
            capture_output=True,
            text=True,
            timeout=500,
        )
        return r, (out / "verify.md").read_text()

    listed = subprocess.run(
        [sys.executable, "-m", "simcli", "verify", "--all", "--list", "--root", str(root)],
        capture_output=True,
        text=True,
        timeout=120,
    ).stdout.splitlines()
    assert [line.split("\t")[:2] for line in listed] == [["fall_m", "measurement"], ["fall_v", "validation"]]
    r, md = verify("fall_m")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "measured" in md and "FAIL" not in md and "not judged" in md
    r, md = verify("fall_v")
    assert r.returncode == 1 and "FAIL" in md


@pytest.mark.validation
@pytest.mark.timeout(1800)
def test_verify_fast_set_passes_end_to_end(tmp_path):
    """`simcli verify` (the fast set) as CI runs it: every case passes, the report is written."""
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "simcli",
            "verify",
            "-o",
            str(tmp_path),
            "--report",
            str(tmp_path / "VALIDATION.md"),
        ],
        capture_output=True,
        text=True,
        timeout=1700,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    text = (tmp_path / "VALIDATION.md").read_text()
    assert "free_fall" in text and "FAIL" not in text
    assert (tmp_path / "verify.csv").read_text().count("\n") >= 5


def test_bottom_pressure_wall_margin_leaves_out_the_side_wall_layers(tmp_path):
    """A synthetic hydrostatic column whose side-wall layers carry 1.7x the pressure (as Akinci's boundary
    term gives): the plain fit is pulled up by them, wall_margin recovers rho0 g H exactly."""
    import h5py
    import yaml

    from simcli.verify.measure import MEASUREMENTS

    ps, W, H = 0.005, 0.2, 0.1
    xs, zs = np.meshgrid(ps * (np.arange(40) + 0.5), ps * (np.arange(20) + 0.5), indexing="ij")
    x = np.stack([xs.ravel(), zs.ravel()], 1)
    p = 1000 * 9.81 * (H - x[:, 1])
    wall = (x[:, 0] < 2 * ps) | (x[:, 0] > W - 2 * ps)
    p[wall] *= 1.7
    scene = {"domain": {"lower": [0.0, 0.0], "upper": [W, 0.2]}}
    with h5py.File(tmp_path / "sim.h5", "w") as f:
        f.attrs["scene"] = yaml.safe_dump(scene)
        f["time"] = np.array([0.0])
        g = f.create_group("entities/water")
        g["position"] = x[None]
        g["pressure"] = p[None]
    with h5py.File(tmp_path / "sim.h5") as f:
        _, plain = MEASUREMENTS["bottom_pressure"](f, "water")
        _, interior = MEASUREMENTS["bottom_pressure"](f, "water", wall_margin=2 * ps)
    assert plain[0] > 1.05 * 981.0
    assert interior[0] == pytest.approx(981.0, rel=1e-9)
