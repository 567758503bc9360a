"""MPM micro-benchmark: the B1 scene (or B1L with --large) straight on the solver, no I/O.

    python benchmarks/mpm_micro.py [--threads 2] [--precision f32] [--large] [--model corotation]
                                   [--material elastic|von_mises|sand|snow|liquid]

``--material`` swaps the cube's material (same geometry) to time the other constitutive laws.
The report also gives the solver's memory: bytes per particle and per grid node of its fields
(counted from the fields themselves), besides the process's peak RSS.

Prints particles, compile time (first substep), and steady throughput in substeps/s and
particle-substeps/s. B1: 0.2 m elastic cube centred at (0, 0, 0.35) in the domain
(-0.5, -0.5, 0)-(0.5, 0.5, 1), grid_density 64, particle_size 0.01 (8,000 particles),
E = 3e5, nu = 0.2, rho = 1000, corotated, dt 4e-3 with 10 substeps, falling onto the floor.
The bodies are sampled here with numpy (cell-centred lattice), not by simcli.geometry, so the
benchmark only measures the solver.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from simcli.backend import init_taichi


def lattice_box(lo, hi, spacing):
    axes = [np.arange(a + spacing / 2, b - spacing / 4, spacing) for a, b in zip(lo, hi)]
    grid = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grid], axis=1)


MATERIALS = {
    "elastic": None,  # MPM.Elastic with --model
    "von_mises": {
        "type": "MPM.ElastoPlastic",
        "E": 3e5,
        "nu": 0.2,
        "rho": 1000.0,
        "von_mises_yield_stress": 3e3,
    },
    "sand": {"type": "MPM.Sand", "E": 3e5, "nu": 0.2, "rho": 1000.0, "friction_angle": 30.0},
    "snow": {"type": "MPM.Snow", "E": 3e5, "nu": 0.2, "rho": 1000.0},
    "liquid": {"type": "MPM.Liquid", "E": 3e5, "nu": 0.2, "rho": 1000.0},
}


def field_bytes(solver) -> dict:
    """Bytes of the solver's Taichi fields per particle and per grid node (all copies)."""
    import taichi as ti

    per_particle = per_node = 0
    seen = set()
    owners = [solver, *solver.laws, solver.boundary]
    for owner in owners:
        for fld in vars(owner).values():
            if not isinstance(fld, (ti.ScalarField, ti.MatrixField)) or id(fld) in seen:
                continue
            seen.add(id(fld))
            comps = fld.n * fld.m if isinstance(fld, ti.MatrixField) else 1
            size = comps * np.dtype(ti.lang.util.to_numpy_type(fld.dtype)).itemsize
            shape = tuple(fld.shape)
            if shape and shape[0] == solver.n:
                per_particle += size
            elif shape[-solver.dim :] == tuple(solver.grid_shape):
                per_node += size * int(np.prod(shape[: -solver.dim]))
    return {
        "bytes_per_particle": per_particle,
        "bytes_per_grid_node": per_node,
        "grid_nodes": int(np.prod(solver.grid_shape)),
    }


def b1_scene(large: bool, model: str, precision: str, threads: int, material: str = "elastic"):
    from simcli.scene.models import Scene

    density, psize, dt = (128.0, 0.005, 1.5e-3) if large else (64.0, 0.01, 4e-3)
    mat = MATERIALS[material] or {"type": "MPM.Elastic", "E": 3e5, "nu": 0.2, "rho": 1000.0, "model": model}
    return Scene.model_validate(
        {
            "sim": {
                "dim": 3,
                "dt": dt,
                "substeps": 10,
                "precision": precision,
                "backend": "cpu",
                "threads": threads,
            },
            "domain": {"lower": [-0.5, -0.5, 0.0], "upper": [0.5, 0.5, 1.0]},
            "solvers": {"mpm": {"grid_density": density, "particle_size": psize}},
            "entities": [
                {
                    "name": "cube",
                    "material": mat,
                    "morph": {"type": "Box", "center": [0.0, 0.0, 0.35], "size": [0.2, 0.2, 0.2]},
                }
            ],
        }
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--precision", default="f32", choices=["f32", "f64"])
    ap.add_argument("--large", action="store_true", help="B1L: grid_density 128, particle_size 0.005")
    ap.add_argument("--model", default="corotation", choices=["corotation", "neohooken"])
    ap.add_argument("--material", default="elastic", choices=list(MATERIALS))
    ap.add_argument("--seconds", type=float, default=5.0, help="time to measure steady stepping [s]")
    ap.add_argument("--json", action="store_true", help="print one JSON line instead of text")
    args = ap.parse_args()

    t0 = time.perf_counter()
    info = init_taichi("cpu", args.precision, args.threads)
    t_init = time.perf_counter() - t0
    from simcli.solvers.base import Body
    from simcli.solvers.mpm import MPMSolver

    scene = b1_scene(args.large, args.model, args.precision, args.threads, args.material)
    ent = scene.entities[0]
    lo, hi = ent.morph.bounds()
    spacing = scene.solvers.mpm.spacing
    x = lattice_box(lo, hi, spacing)
    n = len(x)
    rho = ent.material.rho
    vol_total = float(np.prod(np.subtract(hi, lo)))
    body = Body(
        name=ent.name,
        entity=ent,
        x=x,
        v=np.zeros_like(x),
        volume=np.full(n, vol_total / n),
        mass=np.full(n, rho * vol_total / n),
        fixed=np.zeros(n, bool),
    )

    t0 = time.perf_counter()
    solver = MPMSolver(scene, [body])
    solver.build()
    t_build = time.perf_counter() - t0
    sub_dt = scene.sim.dt / 10
    t0 = time.perf_counter()
    solver.substep(sub_dt)
    solver.frame_check()  # sync
    t_first = time.perf_counter() - t0

    # steady: whole steps of 10 substeps, one frame check per step (like the runner)
    steps = 0
    t0 = time.perf_counter()
    while True:
        for _ in range(10):
            solver.substep(sub_dt)
        stats = solver.frame_check()
        steps += 1
        el = time.perf_counter() - t0
        if el > args.seconds:
            break
    sps = steps * 10 / el
    com_z = float(np.mean(solver.entity_arrays("cube", ["position"])["position"][:, 2]))
    res = {
        "scene": "B1L" if args.large else "B1",
        "model": args.model,
        "precision": args.precision,
        "threads": info["threads"],
        "particles": n,
        "init_s": round(t_init, 3),
        "build_s": round(t_build, 3),
        "first_substep_s": round(t_first, 3),
        "substeps_per_s": round(sps, 1),
        "particle_substeps_per_s": round(sps * n),
        "sim_time_s": round((steps * 10 + 1) * sub_dt, 3),
        "com_z": round(com_z, 4),
        "finite": all(s.finite for s in stats.values()),
        "counts": solver.counts(),
        "material": args.material,
        "memory": field_bytes(solver),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
    }
    if args.json:
        print(json.dumps(res))
    else:
        for k, v in res.items():
            print(f"{k:>24}: {v}")


if __name__ == "__main__":
    main()
