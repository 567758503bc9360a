"""FEM.Cloth cost on a square sheet dropped onto a sphere (contact from the fourth substep on, folds and
self-contact after), beside simcli's PBD cloth on the same sheet.

    PYTHONPATH=. python benchmarks/cloth_bench.py 32 64        # sheet cells per side

Per size: vertices, substeps/s (wall and CPU process time: the machine may be shared), Newton iterations and
contact pairs per substep, the share of PCG, CCD and assembly. PBD: the same sheet, scene and simulated time
through `simcli run` (its steps/s from run.json). FEM.Cloth runs on the host (numpy/scipy/ipctk, float64).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SCENE = """\
version: 1
sim: {{dim: 3, dt: 1.0e-2, substeps: {substeps}, duration: {duration}}}
domain: {{lower: [-1, -1, 0], upper: [1, 1, 1.5], boundary: {{type: slip, friction: 0.5}}}}
colliders:
  - {{type: Sphere, center: [0, 0, 0.3], radius: 0.25, friction: 0.3}}
solvers:
  fem: {{contact_distance: 2.0e-3}}
  pbd: {{particle_size: 0.01, stretch_iterations: 8, bending_iterations: 2}}
entities:
  - name: cloth
    material: {material}
    morph: {{type: Rectangle, center: [0, 0, 0.56], size: [1.0, 1.0], resolution: {n}}}
output: {{every: 1000, formats: [hdf5]}}
"""
FEM = "{type: FEM.Cloth, E: 1.0e6, nu: 0.3, rho: 400, thickness: 5.0e-4, damping: 0.5}"
PBD = (
    "{type: PBD.Cloth, rho: 0.2, stretch_compliance: 1.0e-7, bending_compliance: 1000.0, air_resistance: 1.0}"
)


def fem(n: int, steps: int) -> dict:
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.cloth.solver import ClothSolver

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.yaml"
        p.write_text(SCENE.format(substeps=1, duration=steps * 0.01, material=FEM, n=n))
        ld = load_scene(p)
    s = ClothSolver(ld.scene, [], scene_dir=None)
    s.build()
    w0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        s.substep(0.01)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    st = s.info()
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections

    return {
        "code": "FEM.Cloth",
        "cells": n,
        "vertices": s.n,
        "substeps": steps,
        "substeps_per_s_wall": steps / wall,
        "substeps_per_s_cpu": steps / cpu,
        "newton_per_substep": st["newton_per_substep"],
        "max_newton": st["max_newton"],
        "contacts_per_substep": st["contacts_per_substep"],
        "max_contacts": st["max_contacts"],
        "pcg_share": st["solve_s"] / wall,
        "ccd_share": st["ccd_s"] / wall,
        "assemble_share": st["assemble_s"] / wall,
        "min_gap_m": st.get("min_distance"),
        "intersections_at_end": len(edge_triangle_intersections(s.x, s.tris)),
    }


def pbd(n: int, steps: int) -> dict:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.yaml"
        p.write_text(SCENE.format(substeps=10, duration=steps * 0.01, material=PBD, n=n))
        out = Path(d) / "out"
        r = subprocess.run(
            [sys.executable, "-m", "simcli", "run", str(p), "-o", str(out), "-q"],
            capture_output=True,
            text=True,
        )
        if r.returncode:
            raise SystemExit(r.stderr)
        info = json.loads((out / "run.json").read_text())
    stepping = info["timings"]["stepping_s"]
    return {
        "code": "PBD.Cloth (Taichi cpu, 10 substeps of 1 ms, 8 + 2 iterations)",
        "cells": n,
        "vertices": (n + 1) ** 2,
        "substeps": steps * 10,
        "substeps_per_s_wall": steps * 10 / stepping,
    }


if __name__ == "__main__":
    sizes = [int(a) for a in sys.argv[1:]] or [32]
    for n in sizes:
        steps = 40 if n <= 32 else 12
        print(json.dumps(fem(n, steps)), flush=True)
        print(json.dumps(pbd(n, steps)), flush=True)
