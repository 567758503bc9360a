"""The coupling phase's share of a coupled substep (docs/PERFORMANCE.md, docs/COUPLING.md).

    PYTHONPATH=. python benchmarks/coupling_cost.py configs/validation/coupling_float_2d.yaml --substeps 400

Builds the scene's solvers and coupler as `simcli run` does, warms up (compilation), then times N substeps
with a sync after each phase (pre_couple, couple, post_couple: the syncs cost a little, so the total is a bit
above an unprofiled run) and prints the shares, the coupling fields' memory and the particle counts as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--substeps", type=int, default=400)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--dt", type=float, default=None, help="substep [s] (default: the solvers' stable one)")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args(argv)

    from simcli.backend import init_taichi
    from simcli.coupling import make_coupler
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.loader import load_scene
    from simcli.solvers import make_solvers

    loaded = load_scene(args.scene)
    scene = loaded.scene
    info = init_taichi("cpu", scene.sim.precision, args.threads, quiet=True)
    bodies = sample_scene(scene, loaded.scene_dir, scene.sim.seed)
    solvers = make_solvers(scene, bodies, scene_dir=loaded.scene_dir)
    coupler = make_coupler(scene, solvers)
    if coupler is None:
        print("no coupled pair in this scene", file=sys.stderr)
        return 2
    coupler.prepare()
    for s in solvers:
        s.build()
    coupler.build()
    dt = args.dt or min(float(s.stable_dt()) for s in solvers)
    for _ in range(args.warmup):
        coupler.substep(dt)
    coupler.profile = True
    coupler.times = {k: 0.0 for k in coupler.times}
    t0 = time.perf_counter()
    for _ in range(args.substeps):
        coupler.substep(dt)
    wall = time.perf_counter() - t0
    tot = sum(coupler.times.values())
    counts = {s.family: s.counts() for s in solvers}
    # the coupled particles of the families other than MPM (FEM: its vertices); a pair without MPM counts both
    other = sum(int(c.get("particles", c.get("vertices", 0))) for f, c in counts.items() if f != "mpm")
    mpm = next((s for s in solvers if s.family == "mpm"), None)
    nodes = int(np.prod(mpm.grid_shape)) if mpm is not None else 0
    mem = coupler.memory_bytes() + nodes * (8 if scene.sim.precision == "f64" else 4)  # + MPM's grid_m
    out = {
        "scene": args.scene,
        "threads": info["threads"],
        "dt": dt,
        "substeps": args.substeps,
        "ms_per_substep": 1e3 * wall / args.substeps,
        "share": {k: v / tot for k, v in coupler.times.items()},
        "pairs": coupler.names,
        "counts": counts,
        "mpm_grid_nodes": nodes,
        "coupling_bytes": mem,
        "bytes_per_coupled_particle": mem / max(1, other),
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
