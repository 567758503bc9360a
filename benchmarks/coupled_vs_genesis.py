#!/usr/bin/env python3
"""Genesis's coupling examples beside the same scenes in simcli (issue 20, docs/PERFORMANCE.md).

    PYTHONPATH=. python benchmarks/coupled_vs_genesis.py C1 C2 --rounds 3 --threads 2 --steps 30

Each round runs, one after the other, Genesis (``benchmarks/genesis_coupling_bench.py`` in its own
virtualenv: $GENESIS_PYTHON or ~/genesis-venv/bin/python) and simcli (``simcli run`` of the scene in
configs/bench/) on each scene, so that both see the same load on a shared machine; the table keeps the
fastest round of each. Both are timed over the same steps: the first step (kernel compilation) and
``--warm`` more are left out, then ``--steps`` steps are timed, each one whole (the emitter's entries,
every substep, the sync at its end). simcli's per-step times come from a wrapper around
``Runner._advance_step`` (nothing in simcli changes). Prints one JSON line per run and the table.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = {  # id -> (simcli scene, genesis_coupling_bench.py arguments or None, simcli --set overrides)
    "C1": ("configs/bench/c1_sph_mpm.yaml", ["sph_mpm"], []),
    "C2": ("configs/bench/c2_sand_wheel.yaml", ["sand_wheel", "--sway", "0"], []),
    # C1's families alone (simcli only): where its substep goes
    "C1sph": (
        "configs/bench/c1_sph_mpm.yaml",
        None,
        [
            "entities=[{name: water, material: {type: SPH.Liquid, rho: 1000, stiffness: 50000, exponent: 7, "
            "mu: 0.005, gamma: 0.01}, morph: {type: Box, center: [0.4, 0.5, 0.25], size: [0.7, 0.9, 0.5]}}]"
        ],
    ),
    "C1mpm": (
        "configs/bench/c1_sph_mpm.yaml",
        None,
        [
            "entities=[{name: duck, material: {type: MPM.Elastic, E: 3.0e5, nu: 0.2, rho: 200, "
            "model: corotation}, morph: {type: Mesh, file: genesis_duck.ply, scale: 0.07, "
            "rotate: [90, 0, 90], "
            "translate: [0.5, 0.5, 0.7]}}]"
        ],
    ),
    # C2 with its wheels still (no motion: no per-substep pose upload)
    "C2still": (
        "configs/bench/c2_sand_wheel.yaml",
        None,
        [f"colliders.{k}.motion=null" for k in (1, 2, 3, 4)],
    ),
    # C2 without its four wheels (the plane kept): simcli only, for the wheels' share of the substep
    "C2nw": (
        "configs/bench/c2_sand_wheel.yaml",
        None,
        ["colliders=[{type: Plane, point: [0, 0, 0], normal: [0, 0, 1], friction: 0.2}]"],
    ),
}

# Runs `simcli run ...` with each step's end time recorded (perf_counter after the step's sync) and
# printed as STEP_TIMES [...] on stderr, with the peak RSS.
_WRAP = r"""
import json, resource, sys, time
import simcli.runner as R
_orig = R.Runner._advance_step
T = []
def _timed(self, solvers, loop):
    r = _orig(self, solvers, loop)
    T.append(time.perf_counter())
    return r
R.Runner._advance_step = _timed
from simcli.cli import main
sys.argv = ["simcli"] + sys.argv[1:]
try:
    rc = main()
except SystemExit as e:
    rc = e.code
print("STEP_TIMES " + json.dumps(T), file=sys.stderr)
print("PEAK_RSS_MB %.1f" % (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0), file=sys.stderr)
sys.exit(rc or 0)
"""


def run_simcli(scene: str, threads: int, warm: int, steps: int, sets: list[str]) -> dict:
    n = 1 + warm + steps
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-c", _WRAP, "run", str(ROOT / scene), "-o", out, "--quiet", "--json"]
        cmd += ["--set", f"sim.threads={threads}", "--set", f"sim.steps={n}"]
        for kv in sets:
            cmd += ["--set", kv]
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
        wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"simcli failed ({r.returncode}): {r.stderr[-2000:]}")
    info = json.loads(r.stdout)
    ts = json.loads(re.search(r"^STEP_TIMES (.*)$", r.stderr, re.MULTILINE).group(1))
    peak = float(re.search(r"^PEAK_RSS_MB (.*)$", r.stderr, re.MULTILINE).group(1))
    sub = int(info["substeps"]["fixed"] or 0) or None
    el = ts[-1] - ts[warm]  # steps warm+2 .. n (1-based), the same window as Genesis's
    counts = info.get("counts", {})
    return {
        "code": "simcli",
        "scene": scene,
        "threads": info.get("threads"),
        "particles": info.get("particles"),
        "counts": counts,
        "steady_steps": len(ts) - 1 - warm,
        "steady_s": round(el, 3),
        "substeps_per_s": round((len(ts) - 1 - warm) * sub / el, 2) if sub else None,
        "first_step_s": info["timings"].get("time_to_first_step_s"),
        "compile_s": info["timings"].get("compile_s"),
        "peak_mb": peak,
        "process_wall_s": round(wall, 1),
        "colliders": {k: v for k, v in (info.get("colliders") or {}).items()},
    }


def run_genesis(py: str, args: list[str], threads: int, warm: int, steps: int) -> dict:
    cmd = [py, str(ROOT / "benchmarks" / "genesis_coupling_bench.py"), *args]
    cmd += ["--steps", str(steps), "--warm", str(warm), "--max_s", "3000"]
    env = dict(os.environ, QD_NUM_THREADS=str(threads))
    env.pop("PYTHONPATH", None)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    wall = time.perf_counter() - t0
    m = re.search(r"^RESULT (.*)$", r.stdout, re.MULTILINE)
    if not m:
        raise RuntimeError(f"genesis failed ({r.returncode}): {r.stderr[-2000:]}")
    d = json.loads(m.group(1))
    d.update(code="genesis", process_wall_s=round(wall, 1))
    return d


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--warm", type=int, default=2)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--no-genesis", action="store_true")
    ap.add_argument("--log", default=None, help="append each run's JSON line to this file")
    args = ap.parse_args()
    py = os.environ.get("GENESIS_PYTHON") or str(Path.home() / "genesis-venv" / "bin" / "python")
    have_genesis = not args.no_genesis and Path(py).exists()
    best: dict = {}
    for rnd in range(args.rounds):
        for sid in args.scenes:
            scene, gargs, sets = SCENES[sid]
            runs = []
            if have_genesis and gargs:
                runs.append(("genesis", lambda: run_genesis(py, gargs, args.threads, args.warm, args.steps)))
            runs.append(("simcli", lambda: run_simcli(scene, args.threads, args.warm, args.steps, sets)))
            if rnd % 2:  # alternate which code goes first
                runs.reverse()
            for code, fn in runs:
                load0 = os.getloadavg()[0]
                try:
                    d = fn()
                except Exception as ex:  # one failed run must not lose the others
                    d = {"code": code, "error": str(ex)[-500:]}
                d.update(
                    id=sid, round=rnd, load_before=round(load0, 1), load_after=round(os.getloadavg()[0], 1)
                )
                line = json.dumps(d)
                print(line, flush=True)
                if args.log:
                    with open(args.log, "a") as f:
                        f.write(line + "\n")
                if d.get("substeps_per_s") and d["substeps_per_s"] > best.get((sid, code), {}).get(
                    "substeps_per_s", 0
                ):
                    best[(sid, code)] = d
    print("\n| scene | code | substeps/s (fastest of %d) | ratio |" % args.rounds)
    print("|---|---|---|---|")
    for sid in args.scenes:
        s, g = best.get((sid, "simcli")), best.get((sid, "genesis"))
        for code, d in (("simcli", s), ("genesis", g)):
            if d:
                ratio = (
                    f"{s['substeps_per_s'] / g['substeps_per_s']:.2f}x"
                    if (s and g and code == "simcli")
                    else ""
                )
                print(f"| {sid} | {code} | {d['substeps_per_s']} | {ratio} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
