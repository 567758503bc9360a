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
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--dt", type=float, default=3.0e-3)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--scene", default="configs/bench/sph_dambreak_splishsplash.yaml")
    ap.add_argument(
        "--boundary", choices=["particles", "volume_map"], default=None, help="solvers.sph.boundary"
    )
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--warm", type=int, default=5, help="substeps before the timed ones (the first compile)")
    ap.add_argument("--dump", default=None, help="save the final positions (entity order) to this .npy")
    ap.add_argument(
        "--chunks",
        type=int,
        default=10,
        help="also time the substeps in this many chunks and report the fastest chunk's process CPU time "
        "per substep (on a shared machine the least disturbed figure)",
    )
    ap.add_argument("--no-profiler", action="store_true", help="CPU times without the kernel profiler")
    args = ap.parse_args()
    import taichi as ti

    ti.init(
        arch=ti.cpu, default_fp=ti.f32, cpu_max_num_threads=args.threads, kernel_profiler=not args.no_profiler
    )
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.loader import load_scene
    from simcli.solvers.sph.solver import SPHSolver

    sets = list(args.sets) + ([] if args.boundary is None else [f"solvers.sph.boundary={args.boundary}"])
    scene = load_scene(args.scene, sets).scene
    bodies = [b for b in sample_scene(scene, Path(args.scene).parent) if b.entity.family == "SPH"]
    s = SPHSolver(scene, bodies, Path(args.scene).parent)
    s.build()
    for _ in range(args.warm):  # the first compiles
        s.substep(args.dt)
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    c0, w0 = time.process_time(), time.perf_counter()
    per = max(1, args.substeps // max(1, args.chunks))
    chunk_ms = []
    for k in range(args.substeps):
        if k % per == 0:
            ck = time.process_time()
        s.substep(args.dt)
        if k % per == per - 1:
            ti.sync()
            chunk_ms.append(1e3 * (time.process_time() - ck) / per)
    ti.sync()
    c1, w1 = time.process_time(), time.perf_counter()
    if args.dump:
        import numpy as np

        np.save(args.dump, s._full("position"))
    fastest = total = None
    if not args.no_profiler:
        ti.profiler.print_kernel_profiler_info()  # the table, kernel by kernel
        from taichi.profiler.kernel_profiler import get_default_kernel_profiler

        stats = get_default_kernel_profiler()._statistical_results.values()  # filled by the print above
        fastest = round(sum(st.counter * st.min_time for st in stats) / args.substeps, 3)
        total = round(sum(st.total_time for st in stats) / args.substeps, 3)
    r = s.dfsph_stats.report() if s.opts.pressure_solver == "DFSPH" else {}
    out = {
        "threads": args.threads,
        "boundary": s.opts.boundary,
        "cpu_ms_per_substep": round(1e3 * (c1 - c0) / args.substeps, 3),
        "wall_ms_per_substep": round(1e3 * (w1 - w0) / args.substeps, 3),
        "cpu_ms_per_substep_fastest_chunk": round(min(chunk_ms), 3),
        "cpu_ms_per_substep_chunks": [round(c, 2) for c in chunk_ms],
        "kernel_ms_per_substep_sum_of_fastest": fastest,
        "kernel_ms_per_substep_measured": total,
        "density_iterations": r.get("density", {}).get("iterations_per_substep"),
        "density_substeps_at_cap": r.get("density", {}).get("substeps_at_cap"),
        "divergence_iterations": r.get("divergence", {}).get("iterations_per_substep"),
        "load_average": open("/proc/loadavg").read().split()[0],
    }
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
