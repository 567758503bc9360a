"""Cost per MPM substep with and without CPIC (docs/MPM.md, CPIC): the scene's CPIC colliders on and off,
both solvers in one process, 100 substeps x 5 interleaved, the best of each.

    PYTHONPATH=$PWD python benchmarks/mpm_cpic_cost.py configs/validation/mpm_cpic_plate_sand.yaml 200 1e-4

(scene, grid_density, substep [s])."""

import sys
import time

import yaml

sys.path.insert(0, ".")
from simcli.backend import init_taichi  # noqa: E402

init_taichi("cpu", "f32")
import taichi as ti  # noqa: E402

from simcli.geometry.sampling import sample_scene  # noqa: E402
from simcli.scene.models import Scene  # noqa: E402
from simcli.solvers.mpm import MPMSolver  # noqa: E402

path, density = sys.argv[1], int(sys.argv[2])
sol = {}
for cp in (True, False):
    r = yaml.safe_load(open(path))
    r["solvers"]["mpm"]["grid_density"] = density
    for c in r["colliders"]:
        if "cpic" in c:
            c["cpic"] = cp
    scene = Scene.model_validate(r)
    bodies = sample_scene(scene, seed=0)
    s = MPMSolver(scene, bodies)
    t0 = time.perf_counter()
    s.build()
    s.substep(1e-5)
    ti.sync()
    print("cpic" if cp else "off", "n", s.n, "build+first substep %.1f s" % (time.perf_counter() - t0))
    sol[cp] = s
dt = float(sys.argv[3]) if len(sys.argv) > 3 else 1e-4
best = {True: 1e9, False: 1e9}
for rep in range(5):
    for cp in (True, False):
        s = sol[cp]
        t0 = time.perf_counter()
        for _ in range(100):
            s.substep(dt)
        ti.sync()
        best[cp] = min(best[cp], (time.perf_counter() - t0) / 100)
print(
    "ms/substep: cpic %.3f, off %.3f, ratio %.2f"
    % (1e3 * best[True], 1e3 * best[False], best[True] / best[False])
)
