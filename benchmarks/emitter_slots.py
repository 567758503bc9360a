"""What reserved emitter slots cost (docs/PERFORMANCE.md, "Emitters: reserved slots"): the same emitted jet
with a capacity of exactly what it emits and with 100x that (1% of the slots active), and the same particles
present from the start as an entity instead of an emitter. Prints the stepping throughput of each.

    python benchmarks/emitter_slots.py [--family mpm|sph] [--active 2000] [--repeat 2]

Each configuration runs in its own process (simcli run); throughput is run.json's substeps per second of
stepping (compile excluded), the fastest of --repeat runs, the configurations alternating.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

HEAD = """\
version: 1
sim: {{dim: 2, dt: 2.0e-3, steps: {steps}, substeps: 10}}
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


def scene(family: str, kind: str, active: int, steps: int) -> str:
    if family == "mpm":
        sp, mat, solvers = 0.0025, "MPM.Liquid", "{mpm: {grid_density: 200, particle_size: 0.0025}}"
    else:
        sp, mat, solvers = 0.0025, "SPH.Liquid", "{sph: {particle_size: 0.0025}}"
    per_layer = round(0.2 / sp)
    layers = max(1, active // per_layer)
    length = layers * sp  # the jet's length at 1 m/s
    text = HEAD.format(steps=steps, solvers=solvers)
    if kind == "block":
        return text + BLOCK.format(mat=mat, ylo=0.9 - length)
    cap = layers * per_layer * (100 if kind == "reserved" else 1)
    return text + EMIT.format(mat=mat, stop=length / 1.0, cap=cap)


def run(text: str, out: Path) -> dict:
    f = out.with_suffix(".yaml")
    f.write_text(text)
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(f), "-o", str(out), "--overwrite", "-q"],
        cwd=ROOT,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        capture_output=True,
        text=True,
    )
    if r.returncode != 0:
        raise SystemExit(r.stderr)
    return json.loads((out / "run.json").read_text())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--family", default="mpm", choices=["mpm", "sph"])
    ap.add_argument("--active", type=int, default=2000)
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    kinds = ["exact", "reserved", "block"]
    best: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as d:
        for _ in range(a.repeat):
            for k in kinds:
                info = run(scene(a.family, k, a.active, a.steps), Path(d) / k)
                sps = info["throughput"]["substeps_per_s"]
                if k not in best or sps > best[k]["sps"]:
                    c = info["counts"][a.family]
                    best[k] = {"sps": sps, "stepping_s": info["timings"]["stepping_s"], "counts": c}
    base = best["exact"]["sps"]
    print(f"| {a.family} | configuration | slots | active at the end | substeps/s | vs exact capacity |")
    print("|---|---|---|---|---|---|")
    for k in kinds:
        slots = {"exact": "capacity = emitted", "reserved": "capacity = 100 x emitted", "block": "no emitter"}[k]
        b = best[k]
        print(
            f"| {a.family} | {k} | {slots} | {b['counts'].get('particles')} | {b['sps']:.1f} | "
            f"{b['sps'] / base:.3f} |"
        )


if __name__ == "__main__":
    main()
