"""Issue 24 / 18.5: bad scenes, sweeps and --set values are refused up front with exit 65 and
file:line:col (never a traceback, an internal error, a hang or a memory blow-up); what does not stop a
run is a warning. Every bound is listed in docs/LIMITS.md."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

from simcli.cli import cli

ROOT = Path(__file__).resolve().parents[2]

GOOD = """\
version: 1
sim: {dim: 3, dt: 2.0e-3, substeps: 10, duration: 0.1}
domain: {lower: [-0.5, -0.5, 0.0], upper: [0.5, 0.5, 1.0]}
entities:
  - name: jelly
    material: {type: MPM.Elastic, E: 3.0e5, nu: 0.2, rho: 1000}
    morph: {type: Box, lower: [-0.1, -0.1, 0.3], upper: [0.1, 0.1, 0.5]}
"""

# nine levels of nine aliases: 9^9 = 387 million values once expanded, from a 700-byte file
LAUGHS = "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
    f"{b}: &{b} [{', '.join(['*' + a] * 9)}]\n" for a, b in zip("abcdefgh", "bcdefghi")
)


def _validate(tmp_path: Path, text: str, *extra: str, name: str = "scene.yaml"):
    p = tmp_path / name
    p.write_text(text)
    r = CliRunner().invoke(cli, ["validate", str(p), *extra])
    # a traceback or an internal error would surface as an exception other than SystemExit
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    return r.exit_code, r.output, str(p)


def _expect(tmp_path, text, where: str, *msg: str, extra=()):
    code, out, path = _validate(tmp_path, text, *extra)
    assert code == 65, out
    assert f"{path}{where}" in out, out
    for m in msg:
        assert m in out, out
    assert "Traceback" not in out


# ------------------------------------------------------------------ the YAML reader


def test_billion_laughs_is_refused_quickly(tmp_path):
    _expect(tmp_path, LAUGHS, ":", "YAML too large", "100,000 values", "aliases")


def test_small_aliases_still_work(tmp_path):
    text = GOOD.replace(
        "material: {type: MPM.Elastic, E: 3.0e5, nu: 0.2, rho: 1000}", "material: &m {type: MPM.Elastic}"
    )
    text += (
        "  - name: jelly2\n    material: *m\n"
        "    morph: {type: Box, lower: [0.2, 0.2, 0.3], upper: [0.3, 0.3, 0.4]}\n"
    )
    code, out, _ = _validate(tmp_path, text)
    assert code == 0, out


def test_recursive_alias(tmp_path):
    _expect(tmp_path, GOOD + "output: &o {formats: [*o]}\n", ":8:", "recursive alias")


def test_deep_nesting(tmp_path):
    _expect(tmp_path, "entities: " + "[" * 50_000 + "]" * 50_000 + "\n", ":1:", "nested more than 64 levels")


def test_unknown_tag_is_refused(tmp_path):
    _expect(
        tmp_path,
        GOOD + "output: !!python/object/new:dict {every: 2}\n",
        ":8:9:",
        "YAML tag 'tag:yaml.org,2002:python/object/new:dict' is not supported",
    )
    _expect(tmp_path, GOOD.replace("rho: 1000", "rho: !!binary AAAA"), ":6:", "is not supported")


def test_explicit_tags_that_do_not_fit_their_value(tmp_path):
    """`!!float abc` raised PyYAML's ValueError (a traceback), `!!float ''` an IndexError."""
    _expect(tmp_path, GOOD.replace("rho: 1000", "rho: !!float abc"), ":6:", "cannot read 'abc' as !!float")
    _expect(tmp_path, GOOD.replace("rho: 1000", "rho: !!float ''"), ":6:", "as !!float")
    _expect(tmp_path, GOOD.replace("substeps: 10", "substeps: !!int x"), ":2:", "as !!int")
    code, out, _ = _validate(tmp_path, GOOD.replace("rho: 1000", "rho: !!float 1000"))
    assert code == 0, out


def test_dates_stay_strings(tmp_path):
    code, out, _ = _validate(tmp_path, GOOD.replace("name: jelly", "name: 2024-01-01"))
    assert code == 0, out


def test_set_values_are_read_by_the_same_reader(tmp_path):
    p = tmp_path / "scene.yaml"
    p.write_text(GOOD)
    for value, msg in (
        ("[" * 200, "nested more than 64 levels"),
        ("&a [1, *a]", "recursive alias"),
        ("!!python/object/apply:os.system [true]", "is not supported"),
        ("[" + ", ".join(line.split(": ", 1)[1] for line in LAUGHS.splitlines()) + "]", "YAML too large"),
    ):
        r = CliRunner().invoke(cli, ["validate", str(p), "--set", f"sim.dt={value}"])
        assert r.exit_code == 65 and msg in r.output and "--set sim.dt=" in r.output, (value, r.output)
        assert r.exception is None or isinstance(r.exception, SystemExit)


def test_devices_and_huge_files_are_not_read(tmp_path):
    r = CliRunner().invoke(cli, ["validate", "/dev/zero"])  # was read until memory ran out
    assert r.exit_code == 65 and "/dev/zero: not a regular file" in r.output, r.output
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (5 * 2**20) + "\n" + GOOD)
    r = CliRunner().invoke(cli, ["validate", str(big)])
    assert r.exit_code == 65 and "too large for a scene or sweep file (at most 4 MiB" in r.output, r.output


def test_empty_file_and_no_entities(tmp_path):
    _expect(tmp_path, "", ":1:1:", "the scene is empty")
    _expect(tmp_path, "# only a comment\n", ":1:1:", "the scene is empty")
    _expect(tmp_path, "version: 1\nentities: []\n", ":2:1: entities:", "no entities")
    _expect(tmp_path, "version: 1\nsim: {dim: 2}\n", ":1:1:", "no entities")


def test_run_refuses_an_empty_scene_before_starting(tmp_path):
    """`run` made an internal error (exit 1) of it; now exit 65 from the same checks as validate."""
    p = tmp_path / "scene.yaml"
    p.write_text("version: 1\nentities: []\n")
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(p), "-o", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert r.returncode == 65, r.stderr
    assert "no entities" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ numbers


@pytest.mark.parametrize(
    "old,new,where",
    [
        ("dt: 2.0e-3", "dt: .inf", ":2:19: sim.dt"),
        ("duration: 0.1", "duration: .inf", ":2:51: sim.duration"),
        ("rho: 1000", "rho: .inf", ":6:59: entities.0.material.rho"),
        ("E: 3.0e5", "E: .inf", ":6:38: entities.0.material.E"),
        ("E: 3.0e5", "E: -.inf", ":6:38: entities.0.material.E"),
        ("nu: 0.2", "nu: .nan", ":6:49: entities.0.material.nu"),
        ("duration: 0.1}", "duration: 0.1, gravity: [.nan, 0, 0]}", ":2:66: sim.gravity.0"),
        ("    morph:", "    velocity: [.inf, 0, 0]\n    morph:", ":7:16: entities.0.velocity.0"),
        (
            "lower: [-0.1, -0.1, 0.3], upper: [0.1, 0.1, 0.5]",
            "center: [.nan, 0, 0.4], size: [0.2, 0.2, 0.2]",
            ":7:33: entities.0.morph.center.0",
        ),
    ],
)
def test_nan_and_inf_are_refused_where_they_are(tmp_path, old, new, where):
    assert old in GOOD
    _expect(tmp_path, GOOD.replace(old, new), where, "must be a finite number")


def test_a_collider_rate_no_step_resolves_is_refused_where_it_is(tmp_path):
    """angular_velocity 1e300 rad/s was a traceback (w t overflowed in the pose's sin) in validate."""
    text = GOOD + (
        "colliders:\n"
        "  - name: c\n"
        "    type: Box\n"
        "    lower: [0.2, 0.2, 0.0]\n"
        "    upper: [0.3, 0.3, 0.1]\n"
        "    motion: {angular_velocity: [0, 0, 1.0e300], pivot: [0.25, 0.25, 0.05]}\n"
    )
    _expect(tmp_path, text, ":13:32:", "colliders.0.motion.angular_velocity", "at most 1e+09")


def test_a_mesh_collider_scale_out_of_range_is_refused_where_it_is(tmp_path):
    """scale: 1e300 overflowed into numpy warnings and an OSError's text as the message."""
    mesh = (ROOT / "configs" / "meshes" / "bunny.ply").as_posix()
    text = GOOD + f"colliders:\n  - {{name: c, type: Mesh, file: {mesh}, scale: 1.0e300}}\n"
    _expect(tmp_path, text, ":9:", "colliders.0.scale", "between 1e-9 and 1e9")


def test_booleans_and_fractions_are_not_numbers(tmp_path):
    """`E: true` was read as 1 Pa; strict types refuse it (and 2.5 for a count)."""
    _expect(
        tmp_path, GOOD.replace("E: 3.0e5", "E: true"), ":6:38: entities.0.material.E", "expected a number"
    )
    _expect(tmp_path, GOOD.replace("duration: 0.1", "steps: 2.5"), ":2:48: sim.steps", "expected an integer")
    _expect(tmp_path, GOOD.replace("duration: 0.1", "steps: 1e20"), ":2:48: sim.steps", "expected an integer")
    _expect(tmp_path, GOOD.replace("dt: 2.0e-3", "dt: '2e-3'"), ":2:19: sim.dt", "expected a number")


@pytest.mark.parametrize(
    "old,new,where,msg",
    [
        ("E: 3.0e5", "E: 1.0e300", ":6:38: entities.0.material.E", "plausible range 1..1e+13 Pa"),
        ("E: 3.0e5", "E: 1.0e-3", ":6:38: entities.0.material.E", "plausible range 1..1e+13 Pa"),
        ("rho: 1000", "rho: 1.0e9", ":6:59: entities.0.material.rho", "plausible range 0.001..100000 kg/m^3"),
    ],
)
def test_material_parameters_have_physical_ranges(tmp_path, old, new, where, msg):
    _expect(tmp_path, GOOD.replace(old, new), where, msg)


@pytest.mark.parametrize(
    "old,new,where",
    [
        ("dt: 2.0e-3", "dt: 1.0e-300", ":2:19: sim.dt"),
        ("duration: 0.1", "duration: 1.0e300", ":2:51: sim.duration"),
        ("duration: 0.1", "steps: 100000000000000000000", ":2:48: sim.steps"),
    ],
)
def test_step_counts_are_bounded(tmp_path, old, new, where):
    code, out, path = _validate(tmp_path, GOOD.replace(old, new))
    assert code == 65 and f"{path}{where}" in out, out
    assert "exceed the 1e+09" in out or "beyond 2,147,483,647" in out, out


def test_substep_total_is_bounded(tmp_path):
    text = GOOD.replace(
        "dt: 2.0e-3, substeps: 10, duration: 0.1", "dt: 1.0e-3, substeps: 100000, steps: 100000"
    )
    _expect(tmp_path, text, ":2:", "1e+10 substeps", "exceed the 1e+09")


def test_coordinates_are_bounded(tmp_path):
    _expect(
        tmp_path,
        GOOD.replace("upper: [0.5, 0.5, 1.0]", "upper: [0.5, 0.5, 1.0e300]"),
        ":3:",
        "domain.upper.2",
    )


def test_threads_beyond_the_cores_warn_and_are_clamped(tmp_path):
    code, out, path = _validate(tmp_path, GOOD.replace("duration: 0.1", "duration: 0.1, threads: 100000"))
    assert code == 0, out
    assert f"{path}:2:65: sim.threads: warning: 100000 threads asked" in out, out
    from simcli.scene.limits import allowed_threads

    assert f"running with {allowed_threads()}" in out


def test_run_never_starts_more_threads_than_cores(tmp_path):
    p = tmp_path / "scene.yaml"
    p.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 2, dt: 4.0e-3, substeps: 4, steps: 2, threads: 100000}
            domain: {lower: [0, 0], upper: [1, 1]}
            solvers: {mpm: {grid_density: 16}}
            entities:
              - {name: b, material: {type: MPM.Elastic}, morph: {type: Box, lower: [0.4, 0.4], upper: [0.6, 0.6]}}
            output: {every: 1, formats: [hdf5]}
            """  # noqa: E501 - a scene line as a user writes it
        )
    )
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(p), "-o", str(out), "-q"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert r.returncode == 0, r.stderr
    assert "sim.threads: warning" in r.stderr
    info = json.loads((out / "run.json").read_text())
    assert 1 <= info["threads"] <= len(os.sched_getaffinity(0)), info["threads"]


# ------------------------------------------------------------------ names


@pytest.mark.parametrize(
    "name", ["../../escaped", "a/b", ".hidden", "a\\0b", "a<b>&c", "x..y", "tab\\tname", ""]
)
def test_entity_names_are_safe_file_and_group_names(tmp_path, name):
    code, out, path = _validate(tmp_path, GOOD.replace("name: jelly", f'name: "{name}"'))
    assert code == 65 and f"{path}:5:11: entities.0.name:" in out, out


def test_scene_name_cannot_leave_the_output_folder(tmp_path):
    _expect(tmp_path, "name: ../../escaped\n" + GOOD, ":1:7: name:", "not allowed")


def test_usual_names_pass(tmp_path):
    for name in ("jelly", "Block_2", "disk-a", "E1e5_res64", "v1.2"):
        code, out, _ = _validate(tmp_path, f"name: {name}\n" + GOOD.replace("name: jelly", f"name: {name}"))
        assert code == 0, (name, out)


# ------------------------------------------------------------------ stability, before allocating


def test_rho_typed_in_g_per_cm3_is_caught_with_rho_named(tmp_path):
    """Issue 18.5: water with rho: 1.0 (g/cm^3) validated, then the run exited 70 naming E only."""
    text = GOOD.replace(
        "type: MPM.Elastic, E: 3.0e5, nu: 0.2, rho: 1000", "type: MPM.Liquid, E: 2.0e6, rho: 1.0"
    )
    _expect(tmp_path, text, ":6:", "entities.0.material.rho:", "stability limit", "looks like g/cm^3")


def test_dt_of_4_seconds_is_caught_with_dt_named(tmp_path):
    _expect(
        tmp_path,
        GOOD.replace("dt: 2.0e-3", "dt: 4"),
        ":2:19: sim.dt:",
        "stability limit",
        "sim.dt is in seconds",
        "sim.substeps >=",
    )


def test_fixed_substeps_too_large_is_refused_by_validate():
    """configs/hard/fixed_substeps_too_large.yaml exited 70 after blowing up; now validate refuses it."""
    p = ROOT / "tests" / "data" / "bad_scenes" / "fixed_substeps_too_large.yaml"
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 65, r.output
    assert f"{p}:7:37: sim.substeps:" in r.output and "sim.substeps >= 60" in r.output, r.output


def test_wcsph_and_explicit_fem_fixed_substeps(tmp_path):
    sph = textwrap.dedent(
        """\
        version: 1
        sim: {dim: 2, dt: 0.01, substeps: 1, steps: 10}
        domain: {lower: [0, 0], upper: [1, 1]}
        solvers: {sph: {pressure_solver: WCSPH, particle_size: 0.01}}
        entities:
          - {name: w, material: {type: SPH.Liquid}, morph: {type: Box, lower: [0.1, 0.1], upper: [0.4, 0.4]}}
        """
    )
    _expect(tmp_path, sph, ":2:", "stability limit", "sound speed")
    ok = sph.replace("substeps: 1,", "substeps: auto,")
    code, out, _ = _validate(tmp_path, ok)
    assert code == 0, out
    fem = textwrap.dedent(
        """\
        version: 1
        sim: {dim: 3, dt: 0.05, substeps: 1, steps: 10}
        solvers: {fem: {integrator: explicit, resolution: 20}}
        entities:
          - name: b
            material: {type: FEM.Elastic}
            morph: {type: Box, lower: [-0.1, -0.1, 0.2], upper: [0.1, 0.1, 0.4]}
        """
    )
    _expect(tmp_path, fem, ":2:", "stability limit", "(explicit)")
    code, out, _ = _validate(tmp_path, fem.replace("explicit", "implicit"))  # backward Euler: no limit
    assert code == 0, out


def test_auto_substeps_and_stable_fixed_substeps_pass(tmp_path):
    code, out, _ = _validate(
        tmp_path, GOOD.replace("substeps: 10", "substeps: auto").replace("dt: 2.0e-3", "dt: 4")
    )
    assert code == 0, out


# ------------------------------------------------------------------ overlaps


def test_overlapping_entities_of_one_family_are_refused(tmp_path):
    text = GOOD + (
        "  - name: jelly2\n    material: {type: MPM.Elastic}\n"
        "    morph: {type: Box, lower: [-0.05, -0.05, 0.35], upper: [0.15, 0.15, 0.55]}\n"
    )
    _expect(
        tmp_path, text, ":10:12: entities.1.morph:", "overlaps entity 'jelly'", "m^3", "42% of the smaller"
    )


def test_touching_entities_pass(tmp_path):
    text = GOOD + (
        "  - name: jelly2\n    material: {type: MPM.Elastic}\n"
        "    morph: {type: Box, lower: [-0.1, -0.1, 0.5], upper: [0.1, 0.1, 0.7]}\n"
    )
    code, out, _ = _validate(tmp_path, text)
    assert code == 0 and "warning" not in out, out


def test_entity_inside_a_collider(tmp_path):
    inside = GOOD + "colliders: [{type: Box, lower: [-0.2, -0.2, 0.2], upper: [0.2, 0.2, 0.6]}]\n"
    _expect(tmp_path, inside, ":7:12: entities.0.morph:", "entirely inside colliders.0 (Box)")
    below = GOOD + "colliders: [{type: Plane, point: [0, 0, 0.6], normal: [0, 0, 1]}]\n"
    _expect(tmp_path, below, ":7:12:", "entirely inside colliders.0 (Plane)")
    partly = GOOD + "colliders: [{type: Sphere, center: [0.1, 0.1, 0.5], radius: 0.05}]\n"
    code, out, path = _validate(tmp_path, partly)
    assert code == 0, out
    assert f"{path}:7:12: entities.0.morph: warning:" in out and "inside colliders.0 (Sphere)" in out, out


# ------------------------------------------------------------------ sweeps


def _sweep(tmp_path: Path, body: str) -> Path:
    (tmp_path / "base.yaml").write_text(GOOD)
    p = tmp_path / "study.yaml"
    p.write_text("version: 1\nbase: base.yaml\n" + body)
    return p


def test_huge_sweep_is_refused_before_expansion(tmp_path):
    vals = "[" + ", ".join(str(1e5 * (1 + i)) for i in range(100)) + "]"
    nus = "[" + ", ".join(str(0.01 * i) for i in range(1, 40)) + "]"
    rhos = "[" + ", ".join(str(900 + i) for i in range(30)) + "]"
    p = _sweep(
        tmp_path,
        f"grid:\n  entities.0.material.E: {vals}\n  entities.0.material.nu: {nus}\n"
        f"  entities.0.material.rho: {rhos}\n",
    )
    for args in (["validate", str(p)], ["sweep", "validate", str(p)]):
        r = CliRunner().invoke(cli, args)
        assert r.exit_code == 65, r.output
        assert f"{p}:3:1: grid: the sweep expands to 117,000 runs" in r.output and "5,000" in r.output, (
            r.output
        )


def test_sweep_file_bombs_are_refused(tmp_path):
    p = _sweep(tmp_path, "grid:\n  sim.dt: [1e-3, 2e-3]\n" + "x" + LAUGHS.replace("\n", "\nx", 1))
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 65 and "YAML too large" in r.output, r.output
    p.write_text("version: 1\nbase: base.yaml\ngrid: &g {sim.dt: [*g]}\n")
    r = CliRunner().invoke(cli, ["sweep", "validate", str(p)])
    assert r.exit_code == 65 and "recursive alias" in r.output, r.output


def test_sweep_runs_get_the_same_checks(tmp_path):
    p = _sweep(tmp_path, "grid:\n  entities.0.material.E: [3.0e5, .inf, true]\n")
    r = CliRunner().invoke(cli, ["validate", str(p)])
    assert r.exit_code == 65, r.output
    assert "must be a finite number (got inf)" in r.output and "expected a number (got True)" in r.output


def test_malformed_thread_variable_is_a_warning_not_a_traceback(tmp_path):
    """SIMCLI_THREADS=abc (or a broken SLURM_CPUS_PER_TASK) is ignored with a warning; the run goes on."""
    import os
    import subprocess
    import sys

    scene = tmp_path / "s.yaml"
    scene.write_text(
        "version: 1\nsim: {dim: 2, dt: 1.0e-3, substeps: 2, steps: 2}\n"
        "domain: {lower: [0, 0], upper: [1, 1]}\nsolvers: {mpm: {grid_density: 16}}\n"
        "entities:\n  - name: b\n    material: {type: MPM.Elastic, E: 1.0e4, nu: 0.3, rho: 1000}\n"
        "    morph: {type: Box, lower: [0.4, 0.4], upper: [0.6, 0.6]}\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "SLURM_CPUS_PER_TASK"}
    env["SIMCLI_THREADS"] = "abc"
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(tmp_path / "out"), "-q"],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "not a whole number" in r.stderr
