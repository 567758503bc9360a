#!/usr/bin/env python3
"""SPH boundary representations side by side on SPlisHSPlasH's dam break (configs/bench/
sph_dambreak_splishsplash.yaml): process CPU time of N substeps at a fixed step, after a few substeps that
compile the kernels, for ``solvers.sph.boundary: particles`` or ``volume_map``. CPU time rather than wall
time: on a shared machine the wall time of the same run scattered by 3x (docs/SPH.md, Performance). Run
each mode several times, alternating::

    for r in 1 2 3; do for m in particles volume_map; do
        PYTHONPATH=$PWD python benchmarks/sph_boundary_cpu.py $m --threads 1; done; done
"""

from __future__ import annotations

import argparse
import json
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("boundary", choices=["particles", "volume_map"])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--dt", type=float, default=3.0e-3)
    ap.add_argument("--substeps", type=int, default=200)
    ap.add_argument("--scene", default="configs/bench/sph_dambreak_splishsplash.yaml")
    args = ap.parse_args()
    import taichi as ti

    ti.init(arch=ti.cpu, default_fp=ti.f32, cpu_max_num_threads=args.threads)
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.loader import load_scene
    from simcli.solvers.sph.solver import SPHSolver

    scene = load_scene(args.scene, [f"solvers.sph.boundary={args.boundary}"]).scene
    s = SPHSolver(scene, sample_scene(scene))
    s.build()
    for _ in range(5):  # compiles
        s.substep(args.dt)
    ti.sync()
    c0, w0 = time.process_time(), time.perf_counter()
    for _ in range(args.substeps):
        s.substep(args.dt)
    ti.sync()
    c1, w1 = time.process_time(), time.perf_counter()
    r = s.dfsph_stats.report() if s.opts.pressure_solver == "DFSPH" else {}
    out = {
        "boundary": args.boundary,
        "threads": args.threads,
        "cpu_s": round(c1 - c0, 3),
        "wall_s": round(w1 - w0, 3),
        "density_iterations": r.get("density", {}).get("iterations_per_substep"),
        "divergence_iterations": r.get("divergence", {}).get("iterations_per_substep"),
        "load_average": open("/proc/loadavg").read().split()[0],
    }
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
