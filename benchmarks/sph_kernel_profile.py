#!/usr/bin/env python3
"""Per-kernel times of simcli's SPH substep on SPlisHSPlasH's dam break (configs/bench/
sph_dambreak_splishsplash.yaml, DFSPH): Taichi's kernel profiler over N substeps at a fixed step, after a few
that compile, plus the process CPU time and the DFSPH iteration counts. On a shared machine the profiler's
fastest launch of each kernel ("min") is the figure that load disturbs least; the summary line gives
sum(count x min) per substep, the kernel time of a substep on a quiet core. Run it for two versions of the
code alternately (docs/SPH.md, Performance, session 10)::

    PYTHONPATH=$PWD python benchmarks/sph_kernel_profile.py --substeps 100 --threads 1
"""

from __future__ import annotations

import argparse
import json
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--dt", type=float, default=3.0e-3)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--scene", default="configs/bench/sph_dambreak_splishsplash.yaml")
    ap.add_argument(
        "--boundary", choices=["particles", "volume_map"], default=None, help="solvers.sph.boundary"
    )
    args = ap.parse_args()
    import taichi as ti

    ti.init(arch=ti.cpu, default_fp=ti.f32, cpu_max_num_threads=args.threads, kernel_profiler=True)
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.loader import load_scene
    from simcli.solvers.sph.solver import SPHSolver

    sets = [] if args.boundary is None else [f"solvers.sph.boundary={args.boundary}"]
    scene = load_scene(args.scene, sets).scene
    s = SPHSolver(scene, sample_scene(scene))
    s.build()
    for _ in range(5):  # compiles
        s.substep(args.dt)
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    c0 = time.process_time()
    for _ in range(args.substeps):
        s.substep(args.dt)
    ti.sync()
    c1 = time.process_time()
    ti.profiler.print_kernel_profiler_info()  # the table, kernel by kernel
    from taichi.profiler.kernel_profiler import get_default_kernel_profiler

    stats = get_default_kernel_profiler()._statistical_results.values()  # filled by the print above
    fastest = sum(st.counter * st.min_time for st in stats) / args.substeps
    total = sum(st.total_time for st in stats) / args.substeps
    r = s.dfsph_stats.report() if s.opts.pressure_solver == "DFSPH" else {}
    out = {
        "threads": args.threads,
        "boundary": s.opts.boundary,
        "cpu_ms_per_substep": round(1e3 * (c1 - c0) / args.substeps, 3),
        "kernel_ms_per_substep_sum_of_fastest": round(fastest, 3),
        "kernel_ms_per_substep_measured": round(total, 3),
        "density_iterations": r.get("density", {}).get("iterations_per_substep"),
        "density_substeps_at_cap": r.get("density", {}).get("substeps_at_cap"),
        "divergence_iterations": r.get("divergence", {}).get("iterations_per_substep"),
        "load_average": open("/proc/loadavg").read().split()[0],
    }
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
