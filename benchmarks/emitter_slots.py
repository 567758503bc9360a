"""What reserved emitter slots cost (docs/PERFORMANCE.md, "Emitters: reserved slots"): the same emitted jet
with a capacity of exactly what it emits and with 100x that (1% of the slots active), and the same particles
present from the start as an entity instead of an emitter. Prints the stepping throughput of each.

    python benchmarks/emitter_slots.py [--family mpm|sph|pbd] [--active 2000] [--repeat 2]

(pbd: 3D, a PBD.Liquid jet from a 0.2 m (x) by 0.1 m (y) nozzle, 200 particles a layer; the first in-plane
axis of a nozzle facing -z is y, see nozzle_frame.)

The three solvers are built in one process and stepped at the same fixed substep (1e-4 s); after a warm-up
(compilation, and the jet let in), each is timed over --substeps substeps, --repeat windows alternating
between the configurations, and the fastest window counts (the machine is shared).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

HEAD = """\
version: 1
sim: {{dim: 2, dt: 2.0e-3, steps: {steps}, substeps: {substeps}}}
domain: {{lower: [0, 0], upper: [1.0, 1.0]}}
solvers: {solvers}
output: {{every: 1000000, formats: [hdf5]}}
"""
# a 0.2 m wide nozzle at 1 m/s: the jet of `active` particles leaves within the first steps and falls
EMIT = """\
emitters:
  - name: jet
    material: {{type: {mat}, rho: 1000}}
    shape: {{type: Rectangle, center: [0.5, 0.9], size: [0.2], normal: [0, -1]}}
    speed: 1.0
    stop: {stop}
    max_particles: {cap}
"""
BLOCK = """\
entities:
  - name: jet
    material: {{type: {mat}, rho: 1000}}
    morph: {{type: Box, lower: [0.4, {ylo}], upper: [0.6, 0.9]}}
    velocity: [0, -1.0]
"""


PBD = """\
version: 1
sim: {{dim: 3, dt: 2.0e-3, steps: {steps}, substeps: 20, gravity: [0, 0, 0]}}
domain: {{lower: [0, 0, 0], upper: [1.0, 0.2, 1.0]}}
solvers: {{pbd: {{particle_size: 0.01}}}}
output: {{every: 1000000, formats: [hdf5]}}
"""


def scene_pbd(kind: str, active: int, steps: int) -> str:
    per_layer = 200
    layers = max(1, active // per_layer)
    length = layers * 0.01
    text = PBD.format(steps=steps)
    if kind == "block":
        return (
            text
            + "entities:\n  - name: jet\n    material: {type: PBD.Liquid, rho: 1000}\n"
            + f"    morph: {{type: Box, lower: [0.4, 0.05, {0.9 - length:.4f}], upper: [0.6, 0.15, 0.9]}}\n"
            + "    velocity: [0, 0, -1.0]\n"
        )
    cap = layers * per_layer * (100 if kind == "reserved" else 1)
    return text + (
        "emitters:\n  - name: jet\n    material: {type: PBD.Liquid, rho: 1000}\n"
        "    shape: {type: Rectangle, center: [0.5, 0.1, 0.9], size: [0.1, 0.2], normal: [0, 0, -1]}\n"
        f"    speed: 1.0\n    stop: {length:.4f}\n    max_particles: {cap}\n"
    )


def scene(family: str, kind: str, active: int, steps: int) -> str:
    if family == "pbd":
        return scene_pbd(kind, active, steps)
    if family == "mpm":
        sp, mat, solvers = 0.0025, "MPM.Liquid", "{mpm: {grid_density: 200, particle_size: 0.0025}}"
    else:
        sp, mat, solvers = 0.0025, "SPH.Liquid", "{sph: {particle_size: 0.0025, pressure_solver: DFSPH}}"
    per_layer = round(0.2 / sp)
    layers = max(1, active // per_layer)
    length = layers * sp  # the jet's length at 1 m/s
    substeps = 20 if family == "mpm" else "auto"  # SPH: its CFL and sound-speed limits
    text = HEAD.format(steps=steps, solvers=solvers, substeps=substeps)
    if kind == "block":
        return text + BLOCK.format(mat=mat, ylo=0.9 - length)
    cap = layers * per_layer * (100 if kind == "reserved" else 1)
    return text + EMIT.format(mat=mat, stop=length / 1.0, cap=cap)


def build(text: str, path: Path):
    """The solver of a scene and its SourceRun, built in this process (Taichi already started)."""
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.loader import load_scene
    from simcli.scene.sources import emitter_bodies
    from simcli.solvers import make_solvers
    from simcli.solvers.sources import make_source_run

    path.write_text(text)
    ld = load_scene(path)
    sc = ld.scene
    bodies = sample_scene(sc, ld.scene_dir, 0) + emitter_bodies(sc)
    solvers = make_solvers(sc, bodies)
    for s in solvers:
        s.build()
    return solvers[0], make_source_run(sc, solvers)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--family", default="mpm", choices=["mpm", "sph", "pbd"])
    ap.add_argument("--active", type=int, default=2000)
    ap.add_argument("--substeps", type=int, default=1000, help="substeps per timed window")
    ap.add_argument("--repeat", type=int, default=3, help="timed windows per configuration (alternating)")
    a = ap.parse_args()
    from simcli.backend import init_taichi

    init_taichi("cpu", "f32", int(os.environ.get("SIMCLI_THREADS", "2")), quiet=True)
    kinds = ["exact", "reserved", "block"]
    dt = 1.0e-4  # below every stability limit of the three scenes
    built = {}
    with tempfile.TemporaryDirectory() as d:
        for k in kinds:
            s, src = build(scene(a.family, k, a.active, 100), Path(d) / f"{k}.yaml")
            t = 0.0
            # warm-up: compile, and let the emitter let its particles in (the jet's length at 1 m/s)
            while t < 0.1:
                if src is not None:
                    src.before_substep(t)
                s.substep(dt)
                t += dt
            s.sync()
            built[k] = [s, src, t, []]
        for _ in range(a.repeat):
            for k in kinds:
                s, src, t, times = built[k]
                t0 = time.perf_counter()
                for _ in range(a.substeps):
                    if src is not None:
                        src.before_substep(t)  # what the runner calls before each substep
                    s.substep(dt)
                    t += dt
                s.sync()
                times.append(time.perf_counter() - t0)
                built[k][2] = t
    base = a.substeps / min(built["exact"][3])
    print(
        f"| {a.family} | configuration | particle slots | active | substeps/s (best of {a.repeat}) | vs "
        "exact |"
    )
    print("|---|---|---|---|---|---|")
    for k in kinds:
        s, src, _t, times = built[k]
        slots = {
            "exact": "capacity = emitted",
            "reserved": "capacity = 100 x emitted",
            "block": "no emitter",
        }[k]
        active = src.solvers[0].active_set.n_active if src is not None else s.n
        sps = a.substeps / min(times)
        print(f"| {a.family} | {k} | {slots} ({s.n:,}) | {active:,} | {sps:.1f} | {sps / base:.3f} |")


if __name__ == "__main__":
    main()
