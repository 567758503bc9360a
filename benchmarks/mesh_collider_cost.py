"""Cost per substep of a rotating Mesh collider against the same MPM scene with a still primitive (issue 19).

    PYTHONPATH=. python benchmarks/mesh_collider_cost.py [--grid 64] [--substeps 200] [--repeats 3]

One process, f32 on the CPU: the sand bed of configs/validation/mpm_mesh_paddle_sand.yaml (grid 64) with, in
turn, (a) a still Cylinder collider of the paddle's reach, (b) the star Mesh paddle still, (c) the star Mesh
paddle turning at 2 rev/s, (d) the star Mesh in motion at zero speed, (e) a Box paddle turning at 2 rev/s.
Each variant is built and warmed up (its
kernels compiled), then timed over --substeps substeps; the variants are timed in turn --repeats times
(interleaved, so a load change on a shared machine hits them alike); reported: the median CPU time of the
process per substep (all threads; less disturbed by other processes than wall time), also with the per-substep
pose upload of moving colliders (ColliderPoses.set_time) held, and the SDF construction time of the Mesh.
A Mesh in motion at zero speed separates the collider's own cost from the cost of the sand being stirred
(a rotating Box stirs it alike)."""

import argparse
import math
import statistics
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

W = 4 * math.pi
VARIANTS = {
    "still Cylinder (primitive)": {
        "type": "Cylinder",
        "center": [0.2, 0.2, 0.08],
        "radius": 0.12,
        "height": 0.08,
    },
    "still Mesh (star)": {"type": "Mesh", "file": "star_paddle.obj"},
    "rotating Mesh (star, 2 rev/s)": {
        "type": "Mesh",
        "file": "star_paddle.obj",
        "motion": {"angular_velocity": [0, 0, W]},
    },
    "Mesh (star) in motion at zero speed": {
        "type": "Mesh",
        "file": "star_paddle.obj",
        "motion": {"angular_velocity": [0, 0, 0]},
    },
    "rotating Box (2 rev/s)": {
        "type": "Box",
        "lower": [0.08, 0.185, 0.04],
        "upper": [0.32, 0.215, 0.12],
        "motion": {"angular_velocity": [0, 0, W]},
    },
}


def build(col: dict, grid: int):
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.models import Scene
    from simcli.solvers.mpm import MPMSolver

    if col["type"] == "Mesh":
        col = dict(col, scale=[0.12, 0.12, 0.08], translate=[0.2, 0.2, 0.08])
    scene = Scene.model_validate(
        {
            "domain": {"lower": [0, 0, 0], "upper": [0.4, 0.4, 0.2]},
            "colliders": [dict(col, name="paddle", friction=0.3)],
            "solvers": {"mpm": {"grid_density": grid}},
            "entities": [
                {
                    "name": "sand",
                    "material": {"type": "MPM.Sand", "E": 1e6, "nu": 0.3, "rho": 1600, "friction_angle": 30},
                    "morph": {"type": "Box", "lower": [0, 0, 0], "upper": [0.4, 0.4, 0.1]},
                }
            ],
        }
    )
    meshes = ROOT / "configs" / "meshes"
    t0 = time.perf_counter()
    s = MPMSolver(scene, sample_scene(scene, meshes, 0), scene_dir=meshes)
    s.build()
    build_s = time.perf_counter() - t0
    return s, build_s


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--substeps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: Taichi's, all cores)")
    a = ap.parse_args()
    from simcli.backend import init_taichi

    init_taichi("cpu", "f32", threads=a.threads)
    import taichi as ti

    solvers = {}
    for name, col in VARIANTS.items():
        s, b = build(col, a.grid)
        for _ in range(100):  # compile, warm up, and let the paddle stir the sand
            s.substep(2e-4)
        ti.sync()
        solvers[name] = s
        if col["type"] == "Mesh":
            m = s.boundary.colliders[0].mesh
            print(
                f"{name}: SDF grid {'x'.join(map(str, m.shape))} (cell {m.h:.4g} m, {len(m.triangles)} "
                "triangles) "
                f"built in {m.build_seconds:.3f} s; solver build {b:.2f} s"
            )
    cpu: dict[str, list[float]] = {k: [] for k in solvers}
    cpu_no_upload: dict[str, list[float]] = {k: [] for k in solvers}

    def block(s) -> float:
        ti.sync()
        c0 = time.process_time()
        for _ in range(a.substeps):
            s.substep(2e-4)
        ti.sync()
        return (time.process_time() - c0) / a.substeps

    for _ in range(a.repeats):
        for name, s in solvers.items():
            cpu[name].append(block(s))
            upload = s.boundary.set_time
            s.boundary.set_time = lambda t, dt: None  # the pose held: the kernels' own cost
            cpu_no_upload[name].append(block(s))
            s.boundary.set_time = upload
    base = statistics.median(cpu["still Cylinder (primitive)"])
    n = len(next(iter(solvers.values())).entity_arrays("sand", ["position"])["position"])
    print(
        f"grid {a.grid}, {n} particles, {a.substeps} substeps x {a.repeats} interleaved repeats, CPU time, "
        f"threads {a.threads or 'all'}"
    )
    print(
        "| collider | CPU ms per substep | vs still Cylinder | without the pose upload | vs still Cylinder |"
    )
    print("|---|---|---|---|---|")
    for name in solvers:
        c, c2 = statistics.median(cpu[name]), statistics.median(cpu_no_upload[name])
        print(
            f"| {name} | {1e3 * c:.3f} | {100 * (c / base - 1):+.1f}% | {1e3 * c2:.3f} | "
            f"{100 * (c2 / base - 1):+.1f}% |"
        )


if __name__ == "__main__":
    main()
