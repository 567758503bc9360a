"""validate refuses an output field an entity cannot write, with its location (review 2026-11-27: FEM.Cloth
`fields: [position, bogus]` passed validate and run exited 1), and the Taichi-free table it checks against
is the solvers' own list."""

from __future__ import annotations

import subprocess
import sys
import types

from simcli.scene.output_fields import FIELDS

SCENE = """version: 1
sim: {dim: 3, dt: 1.0e-3, duration: 0.002}
domain: {lower: [0, 0, 0], upper: [1, 1, 1]}
entities:
  - name: water
    material: {type: SPH.Liquid, rho: 1000}
    morph: {type: Box, lower: [0.1, 0.1, 0.1], upper: [0.3, 0.3, 0.3]}
output: {every: 1, fields: %s}
"""


def _validate(tmp_path, text):
    p = tmp_path / "s.yaml"
    p.write_text(text)
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", str(p)], capture_output=True, text=True, timeout=120
    )
    return r.returncode, r.stdout + r.stderr


def test_an_unknown_output_field_is_refused_at_validate_with_its_location(tmp_path):
    rc, out = _validate(tmp_path, SCENE % "[position, pressure]")
    assert rc == 0, out
    rc, out = _validate(tmp_path, SCENE % "[position, bogus]")
    assert rc == 65 and "s.yaml:8:" in out and "bogus" in out and "Traceback" not in out, out
    rc, out = _validate(tmp_path, SCENE % "[position, von_mises]")  # an FEM field on an SPH entity
    assert rc == 65 and "von_mises" in out and "available: position, velocity, density" in out, out


def test_the_table_is_each_solvers_own_list_of_output_fields():
    from simcli.solvers.fem.cloth.solver import ClothSolver
    from simcli.solvers.fem.solver import FEMSolver
    from simcli.solvers.mpm.solver import MPMSolver
    from simcli.solvers.pbd.solver import PBDSolver
    from simcli.solvers.sf.solver import SFSolver
    from simcli.solvers.sph.solver import SPHSolver

    me = types.SimpleNamespace(dim=3)
    for fam, cls in [
        ("MPM", MPMSolver),
        ("SPH", SPHSolver),
        ("PBD", PBDSolver),
        ("FEM", FEMSolver),
        ("FEMCloth", ClothSolver),
        ("SF", SFSolver),
    ]:
        assert set(cls.output_fields(me)) == set(FIELDS[fam]), fam
