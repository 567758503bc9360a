#!/usr/bin/env python3
"""SPH beside its peers on simulated particle-seconds per wall-second (particles x simulated time / stepping
wall time), each code with its own adaptive time step, same machine and thread count (the dam break: the
fastest of --repeat alternating runs per code, default 3; the Genesis rows: one run):

1. SPlisHSPlasH (PyPI ``pysplishsplash``, C++ with OpenMP) on its bundled DamBreakModel scene, DFSPH at
   0.01 % / 0.1 % (the scene's 0.05 % is set to SPlisHSPlasH's and simcli's default 0.01 %), against
   simcli on the same dam break (configs/bench/sph_dambreak_splishsplash.yaml, same particle count).
2. Genesis on B2 (configs/bench/b2_*.yaml): Genesis has no adaptive step, so it runs at B2's fixed step;
   simcli runs B2 with ``substeps: auto``. Both report the average density error they reach (mean over
   particles and frames of max(rho / rho0 - 1, 0), from the density each code computed at the start of its
   last substep), since a larger step is only worth it at equal or better density error.

Writes docs/PERFORMANCE_SPH.md (benchmarks/bench.py appends it to docs/PERFORMANCE.md). Installs nothing:

    python3 -m venv ~/sph-venv && ~/sph-venv/bin/pip install pysplishsplash      # SPlisHSPlasH 2.19
    (Genesis: ~/genesis-venv, see ../shared/bench/README.md)
    python benchmarks/sph_vs_splishsplash.py --threads 2

pysplishsplash 2.19's wheel bundles a libGLdispatch that crashes on import next to a system libGLX; the
script preloads the system's libGLdispatch when it exists.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench import genesis_python, machine  # noqa: E402  (after the sys.path insert above)

SPL_RUN = r"""
import sys, time
import pysplishsplash as sph
base = sph.Exec.SimulatorBase()
base.init(["spl", "--no-gui", "--no-cache", "--stopAt", sys.argv[1], "--output-dir", sys.argv[2],
           sys.argv[3]], "bench")
t0 = time.perf_counter()
base.run()
print("WALL", time.perf_counter() - t0)
"""

GENESIS_RUN = r"""
import sys, time, json
import numpy as np
import genesis as gs
gs.init(backend=gs.cpu, seed=0, precision='32', logging_level='warning')
solver_name, steps = sys.argv[1], int(sys.argv[2])
scene = gs.Scene(sim_options=gs.options.SimOptions(dt=4e-3, substeps=10),
                 sph_options=gs.options.SPHOptions(lower_bound=(-0.5, -0.5, 0.0), upper_bound=(0.5, 0.5, 1.0),
                                                   particle_size=0.02, pressure_solver=solver_name),
                 show_viewer=False)
ent = scene.add_entity(material=gs.materials.SPH.Liquid(),
                       morph=gs.morphs.Box(pos=(-0.3, 0.0, 0.25), size=(0.36, 0.9, 0.46)))
scene.build()
for _ in range(3):
    scene.step()
sph_solver = scene.sim.sph_solver
errs, t0 = [], time.perf_counter()
for k in range(steps):
    scene.step()
    if k % 5 == 4:
        rho = sph_solver.particles_reordered.rho.to_numpy().reshape(-1)
        errs.append(float(np.maximum(rho / 1000.0 - 1.0, 0.0).mean()))
el = time.perf_counter() - t0
print("RESULT " + json.dumps({"n": int(ent.n_particles), "wall": el, "sim_time": steps * 4e-3,
                             "density_error_percent": 100 * float(np.mean(errs))}))
"""


def run_splishsplash(py: str, threads: int, duration: float, work: Path, data: str | None = None) -> dict:
    scene_src = Path(data or Path(py).parent / "data") / "Scenes" / "DamBreakModel.json"
    scene = json.loads(scene_src.read_text())
    scene["Configuration"]["DFSPH"].update(maxError=0.01, maxErrorV=0.1)
    rb = scene["RigidBodies"][0]
    rb["geometryFile"] = str((scene_src.parent / rb["geometryFile"]).resolve())
    (work / "DamBreak.json").write_text(json.dumps(scene, indent=1))
    (work / "run.py").write_text(SPL_RUN)
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    gldispatch = Path("/lib/x86_64-linux-gnu/libGLdispatch.so.0")
    if gldispatch.exists():
        env["LD_PRELOAD"] = str(gldispatch)
    r = subprocess.run(
        [py, str(work / "run.py"), str(duration), str(work / "out"), str(work / "DamBreak.json")],
        capture_output=True,
        text=True,
        env=env,
        timeout=3600,
        check=False,
    )
    out = r.stdout + r.stderr
    if r.returncode != 0:
        raise RuntimeError(f"SPlisHSPlasH failed ({r.returncode}): {out[-2000:]}")

    def num(pattern):
        m = re.search(pattern, out)
        return float(m.group(1)) if m else None

    step_ms = num(r"Time sum: SimStep: ([\d.e+-]+) ms")
    return {
        "particles": int(num(r"Number of fluid particles: (\d+)")),
        "stepping_s": step_ms / 1000.0,
        "sim_time": num(r"Total number: Time step size: ([\d.e+-]+)"),
        "dt_mean": num(r"Average number: Time step size: ([\d.e+-]+)"),
        "density_iterations": num(r"Average number: DFSPH - iterations: ([\d.e+-]+)"),
        "divergence_iterations": num(r"Average number: DFSPH - iterationsV: ([\d.e+-]+)"),
        "setup_s": num(r"time Volume Map Construction: ([\d.e+-]+) ms") / 1000.0,
        "tolerance_percent": 0.01,
    }


def run_simcli(scene: str, threads: int, sets: list[str]) -> dict:
    import h5py

    with tempfile.TemporaryDirectory() as out:
        cmd = [
            sys.executable,
            "-m",
            "simcli",
            "run",
            str(ROOT / scene),
            "-o",
            out,
            "--quiet",
            "--backend",
            "cpu",
            "--set",
            f"sim.threads={threads}",
            "--set",
            "output.fields=[position, velocity, density]",
        ]
        for s in sets:
            cmd += ["--set", s]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=3600, check=False)
        if r.returncode != 0:
            raise RuntimeError(f"simcli failed ({r.returncode}): {r.stderr[-2000:]}")
        info = json.loads((Path(out) / "run.json").read_text())
        with h5py.File(Path(out) / "sim.h5", "r") as f:
            g = next(iter(f["entities"].values()))
            rho = np.asarray(g["density"][1:], dtype=np.float64)
    dfsph = info["solvers"]["sph"].get("dfsph", {})
    sub = info["substeps"]
    return {
        "particles": info["particles"],
        "stepping_s": info["timings"]["stepping_s"],
        "sim_time": info["sim_time"],
        "dt_mean": info["sim_time"] / max(1, sub["total"]),
        "substeps": sub["total"],
        "density_iterations": dfsph.get("density", {}).get("iterations_per_substep"),
        "divergence_iterations": dfsph.get("divergence", {}).get("iterations_per_substep"),
        "solver_density_error_percent_max": dfsph.get("density", {}).get("average_error_percent_max"),
        "density_error_percent": 100 * float(np.maximum(rho / 1000.0 - 1.0, 0.0).mean()),
    }


def run_genesis(py: str, solver: str, threads: int, steps: int, work: Path) -> dict:
    (work / "genesis_run.py").write_text(GENESIS_RUN)
    env = dict(os.environ, QD_NUM_THREADS=str(threads))
    r = subprocess.run(
        [py, str(work / "genesis_run.py"), solver, str(steps)],
        capture_output=True,
        text=True,
        env=env,
        timeout=3600,
        check=False,
    )
    m = re.search(r"^RESULT (.*)$", r.stdout, re.MULTILINE)
    if r.returncode != 0 or not m:
        raise RuntimeError(f"genesis failed ({r.returncode}): {r.stderr[-2000:]}")
    d = json.loads(m.group(1))
    return {
        "particles": d["n"],
        "stepping_s": d["wall"],
        "sim_time": d["sim_time"],
        "dt_mean": 4e-4,
        "density_error_percent": d["density_error_percent"],
    }


def pss(r: dict) -> float:
    return r["particles"] * r["sim_time"] / r["stepping_s"]


def fmt(x, nd=3):
    if x is None:
        return "-"
    return f"{x:.{nd}g}" if isinstance(x, float) else str(x)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--splishsplash-python", default=str(Path.home() / "sph-venv" / "bin" / "python"))
    ap.add_argument("--duration", type=float, default=1.0, help="simulated time of the dam break [s]")
    ap.add_argument("--genesis-steps", type=int, default=25, help="Genesis B2 steps (4 ms each)")
    ap.add_argument(
        "--splishsplash-data",
        default=None,
        help="folder with SPlisHSPlasH's Scenes/ and models/ (default: data/ beside its python)",
    )
    ap.add_argument("--no-genesis", action="store_true", help="skip the Genesis B2 rows")
    ap.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="scene override for simcli's dam break (repeatable)",
    )
    ap.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="run the dam break N times for each code, alternating, and report the fastest (single "
        "runs on a shared machine scatter by up to 2x, SPlisHSPlasH's OpenMP code most)",
    )
    ap.add_argument("--out", default=str(ROOT / "docs" / "PERFORMANCE_SPH.md"))
    args = ap.parse_args()
    lines = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        rows = []
        spl_py = shutil.which(args.splishsplash_python) or args.splishsplash_python
        spl, ours = None, None
        for _ in range(args.repeat):  # alternating, so that a slow spell of a shared machine hits both
            if Path(spl_py).exists():
                r = run_splishsplash(spl_py, args.threads, args.duration, work, args.splishsplash_data)
                print("SPlisHSPlasH", json.dumps(r), flush=True)
                spl = r if spl is None or r["stepping_s"] < spl["stepping_s"] else spl
            r = run_simcli(
                "configs/bench/sph_dambreak_splishsplash.yaml",
                args.threads,
                [f"sim.duration={args.duration}", *args.sets],
            )
            print("simcli", json.dumps(r), flush=True)
            ours = r if ours is None or r["stepping_s"] < ours["stepping_s"] else ours
        if spl is not None:
            rows.append(("SPlisHSPlasH 2.19 (DFSPH)", spl))
        rows.append(("simcli (DFSPH)", ours))
        lines += [
            "### Dam break (SPlisHSPlasH's DamBreakModel), DFSPH at 0.01 % / 0.1 %, adaptive steps",
            "",
            "| code | particles | simulated [s] | stepping wall [s] | mean step [ms] | density / divergence "
            "iterations per step | particle-seconds per wall-second | vs SPlisHSPlasH |",
            "|---|---|---|---|---|---|---|---|",
        ]
        base = pss(rows[0][1]) if len(rows) > 1 else None
        for name, r in rows:
            lines.append(
                f"| {name} | {r['particles']} | {fmt(r['sim_time'])} | {fmt(r['stepping_s'])} | "
                f"{fmt(1e3 * r['dt_mean'])} | {fmt(r['density_iterations'])} / "
                f"{fmt(r['divergence_iterations'])} | {fmt(pss(r))} | "
                f"{fmt(pss(r) / base) + 'x' if base else '-'} |"
            )
        lines += [
            "",
            "Both stop each solve at an average density error of 0.01 % (divergence 0.1 %); simcli's "
            f"largest per-step average density error was {fmt(ours['solver_density_error_percent_max'])} %. "
            "SPlisHSPlasH's one-off volume-map construction (its boundary method) is excluded, as is "
            "simcli's compilation.",
            "",
        ]

        gpy = None if args.no_genesis else genesis_python()
        if gpy:
            grow = []
            for solver, scene in (
                ("WCSPH", "configs/bench/b2_wcsph.yaml"),
                ("DFSPH", "configs/bench/b2_dfsph.yaml"),
            ):
                g = run_genesis(gpy, solver, args.threads, args.genesis_steps, work)
                fixed = run_simcli(scene, args.threads, ["sim.steps=50", "output.every=5"])
                auto = run_simcli(
                    scene, args.threads, ["sim.steps=50", "output.every=5", "sim.substeps=auto"]
                )
                print(
                    solver,
                    "genesis",
                    json.dumps(g),
                    "simcli fixed",
                    json.dumps(fixed),
                    "auto",
                    json.dumps(auto),
                    flush=True,
                )
                grow += [
                    (solver, "Genesis 1.4.5, fixed 0.4 ms", g),
                    (solver, "simcli, fixed 0.4 ms", fixed),
                    (solver, "simcli, substeps: auto", auto),
                ]
            lines += [
                "### B2 dam break: simulated particle-seconds per wall-second",
                "",
                "| solver | code, step | particles | mean substep [ms] | average density error [%] | "
                "particle-seconds per wall-second | vs Genesis |",
                "|---|---|---|---|---|---|---|",
            ]
            for solver in ("WCSPH", "DFSPH"):
                rs = [r for r in grow if r[0] == solver]
                gbase = pss(rs[0][2])
                for _, name, r in rs:
                    lines.append(
                        f"| {solver} | {name} | {r['particles']} | {fmt(1e3 * r['dt_mean'])} | "
                        f"{fmt(r['density_error_percent'])} | {fmt(pss(r))} | {fmt(pss(r) / gbase)}x |"
                    )
            lines += [
                "",
                "Average density error: the mean over particles and frames of max(rho / rho0 - 1, 0), from "
                "the density each code computed at the start of its last substep (Genesis: no boundary "
                "particles, so its particles at walls are under-dense and count as zero).",
                "",
            ]
        if not gpy and args.out and Path(args.out).exists():  # keep the last Genesis section, marked as such
            old = Path(args.out).read_text()
            k = old.find("### B2 dam break")
            if k >= 0:
                kept = old[k:].rstrip("\n").split("\n")
                if "(kept from an earlier run" not in kept[0]:
                    kept[0] += " (kept from an earlier run with Genesis: this run had --no-genesis)"
                lines += kept + [""]
    text = (
        "## SPH beside SPlisHSPlasH and Genesis\n"
        "\n"
        f"Regenerate with `python benchmarks/sph_vs_splishsplash.py` (measured {time.strftime('%Y-%m-%d')} "
        f"on {machine()}; {args.threads} threads for every code, "
        + ("one run" if args.repeat == 1 else f"the fastest of {args.repeat} alternating runs")
        + ", in sequence).\n\n"
        + "\n".join(lines)
        + "\n"
    )
    print(text)
    if args.out:
        Path(args.out).write_text(text)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
