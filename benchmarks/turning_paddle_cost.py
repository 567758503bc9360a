"""Where a turning paddle's extra cost per substep comes from (issue 19's performance line), per kernel task.

    PYTHONPATH=. python benchmarks/turning_paddle_cost.py sort   [--stir 1000] [--substeps 100] [--repeats 2]
                                                          [--grid 64]
    PYTHONPATH=. python benchmarks/turning_paddle_cost.py swap   [--substeps 60] [--repeats 3]
    PYTHONPATH=. python benchmarks/turning_paddle_cost.py census [--substeps 20]

The scene is mesh_collider_cost.py's (the sand bed of configs/validation/mpm_mesh_paddle_sand.yaml at grid 64,
16,000 particles, MPM.Sand, f32), on the CPU with ONE thread and Taichi's kernel profiler: each task of the
substep kernel (1: P2G, 3: grid update, 4: G2P with the return mapping and the particle-collider projection)
is reported with its fastest and median launch (the profiler times wall clock: on a loaded machine read
the fastest), besides the process's CPU time per substep.

* ``sort``: the hypothesis that stirred grains lose their order in memory. The still Cylinder, the turning
  Box and the turning star Mesh stir --stir substeps; then timed as they are, then after ONE permutation of
  every per-particle field (the solver's and its laws') into the order of their 4^3 node block and node
  (what a periodic spatial sort would do), timed again. Also printed: the fraction of consecutive particles
  whose stencil base nodes are more than one node apart (1 - the memory order's locality).
* ``swap``: collider against material state. The still star Mesh and the turning one stir 1250 substeps
  (half a turn: the 4-fold star then coincides with the still one); their per-particle states are then
  loaded into each other's solver, so the four combinations (still / turning collider x sand at rest /
  stirred) are timed alike, interleaved.
* ``census``: which share of the particles the return mapping changes (plastic flow, the apex (separating
  grains), elastic), at rest and stirred, under the still star. Generic: it wraps the sand law's
  ``return_mapping`` (F changed or not, the separation volume vc > 0 after it), so it follows the law's
  code as it changes.
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import benchmarks.mesh_collider_cost as mcc  # noqa: E402

STILL_STAR, TURNING_STAR = "still Mesh (star)", "rotating Mesh (star, 2 rev/s)"
DT = 2e-4
HALF_TURN = 1250  # substeps of DT at 2 rev/s


def particle_fields(s) -> dict:
    """Every per-particle Taichi field of the solver and of its laws (shape (n, ...))."""
    import taichi as ti

    out: dict = {}
    for obj in [s, *s.laws]:
        for k, f in vars(obj).items():
            if isinstance(f, ti.Field) and f.shape[:1] == (s.n,) and all(f is not g for g in out.values()):
                out[f"{type(obj).__name__}.{k}"] = f
    return out


def bases(s) -> np.ndarray:
    x = s.x.to_numpy().astype(np.float64)
    b = np.floor((x - s.origin) * s.inv_dx - 0.5).astype(np.int64)
    return np.clip(b, 0, np.asarray(s.grid_shape) - 1)


def scattered(s) -> float:
    """Share of consecutive particles whose base nodes are more than one node apart (L1)."""
    return float(np.mean(np.abs(np.diff(bases(s), axis=0)).sum(axis=1) > 1))


def permute_block_order(s) -> None:
    b = bases(s)
    shape = tuple((np.asarray(s.grid_shape) + 3) // 4)
    key = np.ravel_multi_index(tuple((b // 4).T), shape) * 64 + np.ravel_multi_index(
        tuple((b % 4).T), (4,) * 3
    )
    perm = np.argsort(key, kind="stable")
    for f in particle_fields(s).values():
        f.from_numpy(f.to_numpy()[perm])
    s.kernels.compute_bbox()


def load_state(s, state: dict) -> None:
    for k, f in particle_fields(s).items():
        f.from_numpy(state[k])
    s.kernels.compute_bbox()


def timed(s, n: int, rec: dict) -> None:
    """n substeps; appends the CPU ms per substep and each substep task's launch times [ms]."""
    import taichi as ti

    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    c0 = time.process_time()
    for _ in range(n):
        s.substep(DT)
    ti.sync()
    rec.setdefault("cpu", []).append(1e3 * (time.process_time() - c0) / n)
    for r in ti.lang.impl.get_runtime().prog.get_kernel_profiler_records():
        if r.name.startswith("substep"):
            rec.setdefault("task " + r.name.split("_kernel_")[-1], []).append(r.kernel_time)


def report(res: dict) -> None:
    print("| case | CPU ms per substep (blocks) | task: fastest / median launch [ms] |")
    print("|---|---|---|")
    for tag, r in res.items():
        tasks = "; ".join(
            f"{k[5:].split('_')[0]}: {min(v):.3f} / {statistics.median(v):.3f}"
            for k, v in sorted(r.items())
            if k != "cpu" and max(v) > 0.02
        )
        print(f"| {tag} | {' '.join(f'{c:.3f}' for c in r['cpu'])} | {tasks} |")


def stirred(names: list[str], stir: int, grid: int = 64) -> dict:
    sol = {}
    for name in names:
        s, _ = mcc.build(mcc.VARIANTS[name], grid)
        for _ in range(stir):
            s.substep(DT)
        sol[name] = s
    return sol


def exp_sort(a) -> None:
    names = ["still Cylinder (primitive)", "rotating Box (2 rev/s)", TURNING_STAR]
    sol = stirred(names, a.stir, a.grid)
    res: dict = {}
    for phase in ("as stirred", "block order"):
        if phase == "block order":
            for s in sol.values():
                permute_block_order(s)
        for name, s in sol.items():
            print(f"{name}, {phase}: {100 * scattered(s):.1f}% of consecutive particles > 1 node apart")
        for _ in range(a.repeats):
            for name, s in sol.items():
                timed(s, a.substeps, res.setdefault(f"{name}, {phase}", {}))
    report(res)


def exp_swap(a) -> None:
    sol = stirred([STILL_STAR, TURNING_STAR], HALF_TURN)
    snap = {nm: {k: f.to_numpy() for k, f in particle_fields(s).items()} for nm, s in sol.items()}
    still, turn = sol[STILL_STAR], sol[TURNING_STAR]
    t_turn = turn.time
    combos = [
        ("still star, sand at rest", still, STILL_STAR),
        ("turning star, stirred sand", turn, TURNING_STAR),
        ("still star, stirred sand", still, TURNING_STAR),
        ("turning star, sand at rest", turn, STILL_STAR),
    ]
    res: dict = {}
    for _ in range(a.repeats):
        for tag, s, src in combos:
            load_state(s, snap[src])
            if s is turn:
                turn.time = t_turn  # the star back at half a turn, where it coincides with the still one
            timed(s, a.substeps, res.setdefault(tag, {}))
    report(res)


def counting(law, orig, cnt):
    """The law's return mapping, counting what it did to each particle into cnt."""
    import taichi as ti

    @ti.func
    def counted(p, F, mid, mu, lam):
        Fn = orig(p, F, mid, mu, lam)
        if law.vc[p] > 0.0:
            ti.atomic_add(cnt[1], 1)
        elif (Fn - F).norm_sqr() > 0.0:
            ti.atomic_add(cnt[0], 1)
        else:
            ti.atomic_add(cnt[2], 1)
        return Fn

    return counted


def exp_census(a) -> None:
    import taichi as ti

    cnt = ti.field(ti.i64, shape=3)  # plastic flow (F changed, vc = 0), apex (vc > 0), elastic
    built = {}
    for name in (STILL_STAR, TURNING_STAR):
        s, _ = mcc.build(mcc.VARIANTS[name], 64)
        law = next(law for law in s.laws if hasattr(law, "vc"))
        law.return_mapping = counting(law, law.return_mapping, cnt)  # before the first launch compiles
        for _ in range(HALF_TURN):
            s.substep(DT)
        built[name] = s
    snap = {nm: {k: f.to_numpy() for k, f in particle_fields(s).items()} for nm, s in built.items()}
    still = built[STILL_STAR]
    for src, tag in ((STILL_STAR, "sand at rest"), (TURNING_STAR, "stirred sand")):
        load_state(still, snap[src])
        cnt.fill(0)
        for _ in range(a.substeps):
            still.substep(DT)
        c = cnt.to_numpy().astype(float)
        c /= c.sum()
        print(f"{tag} under the still star: plastic flow {c[0]:.3f}, apex {c[1]:.3f}, elastic {c[2]:.3f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("experiment", choices=["sort", "swap", "census"])
    ap.add_argument("--stir", type=int, default=1000, help="substeps of stirring before timing (sort)")
    ap.add_argument("--grid", type=int, default=64, help="grid density (sort; 128: 128,000 particles)")
    ap.add_argument("--substeps", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=None)
    a = ap.parse_args()
    defaults = {"sort": (100, 2), "swap": (60, 3), "census": (20, 1)}[a.experiment]
    a.substeps = a.substeps or defaults[0]
    a.repeats = a.repeats or defaults[1]
    import simcli.backend as backend
    from simcli.backend import stdout_to_stderr

    with stdout_to_stderr():
        import taichi as ti
    ti.init(
        arch=ti.cpu,
        default_fp=ti.f32,
        default_ip=ti.i32,
        kernel_profiler=a.experiment != "census",
        cpu_max_num_threads=1,
        offline_cache=True,
        offline_cache_file_path=backend.default_cache_dir(),
        random_seed=0,
    )
    backend._STATE.update({"arch": "x64", "threads": 1, "precision": "f32"})
    {"sort": exp_sort, "swap": exp_swap, "census": exp_census}[a.experiment](a)


if __name__ == "__main__":
    main()
