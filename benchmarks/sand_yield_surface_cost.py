"""Cost per substep of MPM.Sand's yield surfaces (drucker_prager, mohr_coulomb, matsuoka_nakai; issue 23).

    PYTHONPATH=. python benchmarks/sand_yield_surface_cost.py [--stir 600] [--substeps 60] [--repeats 3]
                                                              [--grid 64] [--threads 1]
                                                              [--surfaces drucker_prager,mohr_coulomb]

The scene is mesh_collider_cost.py's sand bed (configs/validation/mpm_mesh_paddle_sand.yaml's bed at grid 64,
16,000 particles, 30 deg sand, f32) with its Box paddle turning at 2 rev/s, built in one process once per
``yield_surface`` of --surfaces (the first must be drucker_prager). The drucker_prager bed is stirred --stir
substeps (plastic flow in about half the grains, see turning_paddle_cost.py census); that state is loaded into
every solver before each timing, so all laws step the same grains from the same state ("stirred"); the same
with the bed at rest, before any stirring ("at rest"). Timed --substeps substeps, interleaved --repeats times,
with Taichi's kernel profiler: the CPU time of the process per substep and each substep task's fastest /
median launch (task 4 is G2P with the return mapping; the profiler times wall clock, so on a loaded machine
read the fastest). Also printed: the share of grains whose plastic volume J_p one substep changed (the apex or
the volume correction; every law's plastic flow keeps the volume, so this is not the share in plastic flow).
"""

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import benchmarks.turning_paddle_cost as tpc  # noqa: E402

W = 4 * math.pi


def build(surface: str, grid: int):
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.models import Scene
    from simcli.solvers.mpm import MPMSolver

    scene = Scene.model_validate(
        {
            "domain": {"lower": [0, 0, 0], "upper": [0.4, 0.4, 0.2]},
            "colliders": [
                {
                    "name": "paddle",
                    "type": "Box",
                    "lower": [0.08, 0.185, 0.04],
                    "upper": [0.32, 0.215, 0.12],
                    "motion": {"angular_velocity": [0, 0, W]},
                    "friction": 0.3,
                }
            ],
            "solvers": {"mpm": {"grid_density": grid}},
            "entities": [
                {
                    "name": "sand",
                    "material": {
                        "type": "MPM.Sand",
                        "E": 1e6,
                        "nu": 0.3,
                        "rho": 1600,
                        "friction_angle": 30,
                        "yield_surface": surface,
                    },
                    "morph": {"type": "Box", "lower": [0, 0, 0], "upper": [0.4, 0.4, 0.1]},
                }
            ],
        }
    )
    s = MPMSolver(scene, sample_scene(scene, ROOT / "configs" / "meshes", 0))
    s.build()
    return s


def changed_share(s, state: dict) -> float:
    """Share of grains whose plastic volume J_p one substep changed (apex or volume correction)."""
    tpc.load_state(s, state)
    s.substep(tpc.DT)
    f = tpc.particle_fields(s)
    jp0 = state[[k for k in state if k.endswith(".Jp")][0]]
    jp1 = f[[k for k in f if k.endswith(".Jp")][0]].to_numpy()
    return float(np.mean(np.abs(jp1 - jp0) > 0) if jp0.shape == jp1.shape else float("nan"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--stir", type=int, default=600)
    ap.add_argument("--substeps", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument(
        "--surfaces", default="drucker_prager,mohr_coulomb", help="comma-separated yield_surface values"
    )
    a = ap.parse_args()
    surfaces = a.surfaces.split(",")
    if surfaces[0] != "drucker_prager":
        ap.error("--surfaces: the first must be drucker_prager (its bed is the one stirred)")
    import simcli.backend as backend
    from simcli.backend import stdout_to_stderr

    with stdout_to_stderr():
        import taichi as ti
    ti.init(
        arch=ti.cpu,
        default_fp=ti.f32,
        default_ip=ti.i32,
        kernel_profiler=True,
        cpu_max_num_threads=a.threads,
        offline_cache=True,
        offline_cache_file_path=backend.default_cache_dir(),
        random_seed=0,
    )
    backend._STATE.update({"arch": "x64", "threads": a.threads, "precision": "f32"})
    sol = {name: build(name, a.grid) for name in surfaces}
    dp = sol["drucker_prager"]
    rest = {k: f.to_numpy() for k, f in tpc.particle_fields(dp).items()}
    t0 = time.perf_counter()
    for _ in range(a.stir):
        dp.substep(tpc.DT)
    print(f"stirred {a.stir} substeps in {time.perf_counter() - t0:.1f} s, {dp.n} particles", file=sys.stderr)
    stirred = {k: f.to_numpy() for k, f in tpc.particle_fields(dp).items()}
    res: dict = {}
    for tag, state in (("at rest", rest), ("stirred", stirred)):
        for name, s in sol.items():  # warm-up (compile) outside the timing
            tpc.load_state(s, state)
            s.substep(tpc.DT)
        for _ in range(a.repeats):
            for name, s in sol.items():
                tpc.load_state(s, state)
                tpc.timed(s, a.substeps, res.setdefault(f"{name}, {tag}", {}))
        for name, s in sol.items():
            print(f"{name}, {tag}: share of grains whose J_p changed {changed_share(s, state):.3f}")
    tpc.report(res)


if __name__ == "__main__":
    main()
