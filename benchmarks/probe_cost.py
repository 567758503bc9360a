"""What probes cost (docs/PERFORMANCE.md, "Probes"): the SPHERIC Test 2 scenes of the validation set
(configs/validation/spheric_test2_{mpm,sph}.yaml: 4 height gauges and 2 pressure probes, sampled every 5 ms
step) stepped in one process, each step followed by a probe sample on the device path (simcli/probes/
device.py, what `simcli run` does) and one on the host path (every field the probes read copied whole to the
host, as before). Prints the stepping time per step and each path's time per sample and share of it.

    python benchmarks/probe_cost.py [--scene mpm|sph|both] [--steps 10] [--warmup 2] [--every 1] [--start 0.5]

Measured from --start (0.5 s: the front has hit the box, every gauge and probe is wet; the steps before it
are run without probes). The substeps of each step follow the solver's stable_dt as `substeps: auto` does
(one check per step). The first --warmup steps (compilation) are not counted; the machine is shared, so
each figure is the median over the counted steps. A sample includes the probes.csv row (written and flushed
as `simcli run` does). The two paths' values are compared on every sample (they must be equal bit for bit).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENES = {
    "mpm": ROOT / "configs/validation/spheric_test2_mpm.yaml",
    "sph": ROOT / "configs/validation/spheric_test2_sph.yaml",
}


def _advance(solver, dt: float) -> int:
    n = max(1, math.ceil(dt / solver.stable_dt(dt) - 1e-9))
    for _ in range(n):
        solver.substep(dt / n)
    solver.sync()
    return n


def bench(family: str, steps: int, warmup: int, every: int, start: float) -> dict:
    from simcli.geometry.sampling import sample_scene
    from simcli.probes.recorder import ProbeRecorder
    from simcli.scene.loader import load_scene
    from simcli.solvers import make_solvers

    path = SCENES[family]
    scene = load_scene(path).scene
    bodies = sample_scene(scene, path.parent, scene.sim.seed)
    (solver,) = make_solvers(scene, bodies, scene_dir=path.parent)
    solver.build()
    out = Path(tempfile.mkdtemp(prefix="probe_cost_"))
    dev = ProbeRecorder(scene, [solver], out, device=True)
    dev.open(None)
    host = ProbeRecorder(scene, [solver], out / "host", device=False)
    dt = scene.sim.dt
    k0 = round(start / dt)
    for _ in range(k0):  # to where the wave has reached the box: every gauge and probe wet
        _advance(solver, dt)
    t_step, t_dev, t_host, subs = [], [], [], []
    for k in range(k0, k0 + warmup + steps):
        t0 = time.perf_counter()
        n = _advance(solver, dt)
        t1 = time.perf_counter()
        if (k + 1) % every:
            continue
        before = dev.timings["probes_s"]
        dev.sample(k + 1)  # the device path and the probes.csv row, as in a run
        t2 = time.perf_counter()
        due = list(range(len(host.probes)))
        ref = host.values(due)
        t3 = time.perf_counter()
        got = dev.values(due)
        for i in due:
            np.testing.assert_array_equal(got[i], ref[i], err_msg=host.probes[i].name)
        if k >= k0 + warmup:
            t_step.append(t1 - t0)
            t_dev.append(dev.timings["probes_s"] - before)
            t_host.append(t3 - t2)
            subs.append(n)
        assert t2 >= t1
    step = statistics.median(t_step)
    return {
        "family": family,
        "particles": solver.n_live(),
        "rows": sum(fs.total[None] for fs, _ in dev._samplers),
        "probes": len(dev.probes),
        "substeps": statistics.median(subs),
        "step_s": step,
        "device_s": statistics.median(t_dev),
        "host_s": statistics.median(t_host),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", choices=["mpm", "sph", "both"], default="both")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--every", type=int, default=1, help="sample every N steps (the scenes: every step)")
    ap.add_argument("--start", type=float, default=0.5, help="simulated time [s] run before measuring")
    ap.add_argument("--arch", default="cpu")
    a = ap.parse_args()
    from simcli.backend import init_taichi

    init_taichi(a.arch, "f32")
    rows = [
        bench(f, a.steps, a.warmup, a.every, a.start)
        for f in (["mpm", "sph"] if a.scene == "both" else [a.scene])
    ]
    print(
        "| scene | particles | probes | substeps/step | stepping [s/step] | device path [ms/sample] (share) "
        "| host path [ms/sample] (share) | particles read |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| SPHERIC Test 2, {r['family'].upper()} | {r['particles']:,} | {r['probes']} "
            f"| {r['substeps']:g} "
            f"| {r['step_s']:.3f} | {1e3 * r['device_s']:.2f} ({100 * r['device_s'] / r['step_s']:.2f} %) "
            f"| {1e3 * r['host_s']:.1f} ({100 * r['host_s'] / r['step_s']:.1f} %) | {r['rows']} |"
        )


if __name__ == "__main__":
    main()
