#!/usr/bin/env python3
"""The block list's cost on compact bodies: B1 and B1L (configs/bench) stepped in one process by two solvers,
one with the block list (blocks.py) and one sweeping the particles' box, alternating chunks of substeps so
that both see the same machine load; prints the fastest chunk of each (substeps/s) and the nodes visited.

    PYTHONPATH=. python benchmarks/mpm_blocks_ab.py [b1|b1l] [--chunks 8] [--substeps 100] [--threads 2]
"""

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene", nargs="?", default="b1")
    ap.add_argument("--chunks", type=int, default=8)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    from simcli.backend import init_taichi

    init_taichi("cpu", "f32", threads=args.threads)
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.loader import load_scene
    from simcli.solvers.mpm import MPMSolver

    loaded = load_scene(ROOT / "configs" / "bench" / f"{args.scene}.yaml")
    scene = loaded.scene
    dt = float(scene.sim.dt) / int(scene.sim.substeps)
    solvers = {}
    for blocks in (True, False):
        s = MPMSolver(scene, sample_scene(scene, loaded.scene_dir, scene.sim.seed))
        s.grid_blocks = blocks
        s.build()
        s.substep(dt)
        solvers[blocks] = s
    best = {True: float("inf"), False: float("inf")}
    import taichi as ti

    for _ in range(args.chunks):
        for blocks, s in solvers.items():
            ti.sync()
            t0 = time.perf_counter()
            for _ in range(args.substeps):
                s.substep(dt)
            ti.sync()
            best[blocks] = min(best[blocks], time.perf_counter() - t0)
    for blocks, s in solvers.items():
        c = s.counts()
        name = "blocks" if blocks else "box   "
        print(
            f"{args.scene} {name}: {args.substeps / best[blocks]:8.1f} substeps/s "
            f"(fastest of {args.chunks} chunks of {args.substeps}), nodes visited {c['active_cells']:,} "
            f"of a box of {c['box_cells']:,}"
        )


if __name__ == "__main__":
    main()
