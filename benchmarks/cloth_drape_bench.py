"""FEM.Cloth cost on the drape example (configs/examples/fem_cloth_drape.yaml: 625 vertices onto a sphere and
the floor), stepped directly for the first N substeps (the sheet reaches the sphere at about 0.1 s).

    PYTHONPATH=. python benchmarks/cloth_drape_bench.py 60 [--profile]

Prints substeps per CPU second of the process (and wall), Newton iterations and contact pairs per substep,
factorisations, the smallest gap and the edge-triangle intersections at the end; --profile adds cProfile's
30 most expensive functions (own time).
"""

from __future__ import annotations

import cProfile
import json
import pstats
import sys
import time
from pathlib import Path


def main(steps: int, profile: bool) -> dict:
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections
    from simcli.solvers.fem.cloth.solver import ClothSolver

    p = Path(__file__).resolve().parents[1] / "configs" / "examples" / "fem_cloth_drape.yaml"
    ld = load_scene(p)
    s = ClothSolver(ld.scene, [], scene_dir=p.parent)
    s.build()
    pr = cProfile.Profile()
    if profile:
        pr.enable()
    w0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        s.substep(0.01)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    if profile:
        pr.disable()
    st = s.info()
    out = {
        "substeps": steps,
        "substeps_per_s_cpu": steps / cpu,
        "substeps_per_s_wall": steps / wall,
        "newton_per_substep": st["newton_per_substep"],
        "max_newton": st["max_newton"],
        "contacts_per_substep": st["contacts_per_substep"],
        "max_contacts": st["max_contacts"],
        "factorizations": st["factorizations"],
        "min_gap_m": st.get("min_distance"),
        "intersections_at_end": len(edge_triangle_intersections(s.x, s.tris)),
    }
    print(json.dumps(out), flush=True)
    if profile:
        pstats.Stats(pr).sort_stats("tottime").print_stats(30)
    return out


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(int(args[0]) if args else 60, "--profile" in sys.argv)
