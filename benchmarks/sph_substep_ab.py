#!/usr/bin/env python3
"""The whole SPH substep of C1's water (configs/bench/c1_sph_mpm.yaml without the duck), two versions of the
code in one process: solver A built with another tree's density.py and non_pressure.py (``--base``, e.g. a
detached worktree of main) and pow in Tait's equation, solver B with this tree's; after ``--warm`` substeps
each, ``--reps`` substeps of each alternately, process CPU time per substep, 1 thread. On a shared machine
this separates two versions where runs in separate processes do not (docs/SPH.md, Performance, session 13)::

    git worktree add --detach /tmp/base main
    PYTHONPATH=$PWD python benchmarks/sph_substep_ab.py --base /tmp/base --reps 20

Only the passes these two modules build are swapped (the rest of the substep is this tree's in both).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import time
from pathlib import Path

WATER = (
    "entities=[{name: water, material: {type: SPH.Liquid, rho: 1000, stiffness: 50000, exponent: 7, "
    "mu: 0.005, gamma: 0.01}, morph: {type: Box, center: [0.4, 0.5, 0.25], size: [0.7, 0.9, 0.5]}}]"
)


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the other tree (its simcli/solvers/sph/*.py)")
    ap.add_argument("--scene", default="configs/bench/c1_sph_mpm.yaml")
    ap.add_argument("--dt", type=float, default=2.0e-4)
    ap.add_argument("--warm", type=int, default=10)
    ap.add_argument("--reps", type=int, default=20)
    args = ap.parse_args()
    import numpy as np
    import taichi as ti

    ti.init(arch=ti.cpu, default_fp=ti.f32, cpu_max_num_threads=1, offline_cache=True, log_level=ti.WARN)
    import simcli.solvers.sph.solver as S
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.loader import load_scene

    sph = Path(args.base) / "simcli" / "solvers" / "sph"
    base_nd = _load("base_density", sph / "density.py").make_neighbours_density
    base_np = _load("base_non_pressure", sph / "non_pressure.py").make_non_pressure
    scene = load_scene(args.scene, [WATER]).scene
    bodies = [b for b in sample_scene(scene, Path(args.scene).parent) if b.entity.family == "SPH"]
    mine = S.make_neighbours_density, S.make_non_pressure, S.SPHSolver._int_exponent
    S.make_neighbours_density, S.make_non_pressure = base_nd, base_np
    S.SPHSolver._int_exponent = lambda self: 0
    a = S.SPHSolver(scene, bodies)
    a.build()
    S.make_neighbours_density, S.make_non_pressure, S.SPHSolver._int_exponent = mine
    b = S.SPHSolver(scene, bodies)
    b.build()
    for _ in range(args.warm):
        a.substep(args.dt)
        b.substep(args.dt)
    ti.sync()
    diff = float(np.abs(a._full("position") - b._full("position")).max())
    res: dict[str, list[float]] = {"base": [], "this tree": []}
    for r in range(args.reps):
        pair = [("base", a), ("this tree", b)]
        for key, s in pair if r % 2 == 0 else pair[::-1]:
            t = time.process_time()
            s.substep(args.dt)
            ti.sync()
            res[key].append(1e3 * (time.process_time() - t))
    print(f"largest position difference after {args.warm} substeps: {diff:.3g} m")
    for key, v in res.items():
        print(f"{key}: fastest {min(v):.2f} ms, median {statistics.median(v):.2f} ms per substep")


if __name__ == "__main__":
    main()
