#!/usr/bin/env python3
"""Benchmarks, side by side with Genesis in one run, on the same machine and thread count.

    python benchmarks/bench.py                 # B1 and B1L, cold and warm, writes docs/PERFORMANCE.md
    python benchmarks/bench.py B1 --no-genesis --threads 2

For each scene it runs ``simcli run configs/bench/<id>.yaml`` twice (cold: an empty kernel
cache; warm: the same cache again) and, when a Genesis virtualenv is found ($GENESIS_PYTHON,
or ~/genesis-venv/bin/python; see ../shared/bench/README.md), ``genesis_bench.py`` with the
same geometry, step sizes and thread count, cold and warm. It prints start-up to the first step,
compile time, steady substeps/s and particle-substeps/s and peak memory, and writes the table
to docs/PERFORMANCE.md with a note of the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("SIMCLI_SHARED", ROOT.parent / "shared"))

# id -> (simcli scene, genesis_bench.py arguments, genesis steady steps)
SCENES = {
    "B1": ("configs/bench/b1.yaml", ["mpm", "--plane", "0"], 200),
    "B1L": (
        "configs/bench/b1l.yaml",
        ["mpm", "--plane", "0", "--grid_density", "128", "--psize", "0.005", "--dt", "1.5e-3"],
        60,
    ),
    "B4": ("configs/bench/b4_explicit.yaml", ["fem", "--plane", "0"], 2000),
    "B4i": ("configs/bench/b4_implicit.yaml", ["fem", "--plane", "0", "--implicit", "1"], 100),
    "B2W": ("configs/bench/b2_wcsph.yaml", ["sph", "--plane", "0"], 60),
    "B2D": ("configs/bench/b2_dfsph.yaml", ["sph", "--plane", "0", "--sph_solver", "DFSPH"], 30),
    "B5": ("configs/bench/b5.yaml", ["sf", "--res", "64"], 100),
    "B3": ("configs/bench/b3.yaml", ["pbd_cloth", "--plane", "0"], 100),
    # B2 at about a million particles (particle_size 0.0053), substeps: auto: GPU-only, not in the default set
    "B2W1M": ("configs/bench/b2_wcsph_1m.yaml", None, 0),
    "B2D1M": ("configs/bench/b2_dfsph_1m.yaml", None, 0),
}
# measured only when named on the command line (too large for a CPU run)
GPU_SCENES = {"B2W1M", "B2D1M"}
# Grid scenes whose pressure-solve accuracy is compared too (see b5_accuracy)
GRID_SCENES = {"B5"}

# Run inside Genesis's venv after genesis_bench.py's SF scene: the relative residual of Genesis's pressure
# equation after its 200 Jacobi sweeps, ||div - L p|| / ||div|| (its own discretisation: collocated, central
# -difference divergence, compact Laplacian with clamped neighbours), on the last step.
_GENESIS_SF_RESIDUAL = """
import sys, runpy, json
import numpy as np
sys.argv = [%r] + sys.argv[1:]
ns = runpy.run_path(sys.argv[0], run_name="__main__")
g = ns["scene"].sim.solvers[-1].grid
div = g.div.to_numpy().astype(np.float64)
p = g.p.to_numpy().astype(np.float64)
pp = np.pad(p, 1, mode="edge")
nb = (pp[2:, 1:-1, 1:-1] + pp[:-2, 1:-1, 1:-1] + pp[1:-1, 2:, 1:-1] + pp[1:-1, :-2, 1:-1]
      + pp[1:-1, 1:-1, 2:] + pp[1:-1, 1:-1, :-2])
r = nb - 6.0 * p - div
print("GENESIS_SF_RESIDUAL "
      + json.dumps({"relative_residual": float(np.linalg.norm(r) / np.linalg.norm(div))}))
"""

# Runs a command and reports the peak RSS of that child alone (KiB on Linux).
_WRAP = (
    "import resource, subprocess, sys, time\n"
    "t = time.perf_counter(); r = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
    "sys.stdout.write(r.stdout); sys.stderr.write(r.stderr)\n"
    "print('BENCH_WRAP', r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, "
    "time.perf_counter() - t, file=sys.stderr)\n"
)


def _run(cmd: list[str], env: dict, timeout: float) -> tuple[int, str, str, float, float]:
    r = subprocess.run(
        [sys.executable, "-c", _WRAP, *cmd], capture_output=True, text=True, env=env, timeout=timeout
    )
    m = re.search(r"BENCH_WRAP (-?\d+) (\d+) ([\d.]+)", r.stderr)
    if not m:
        raise RuntimeError(f"benchmark wrapper failed: {r.stderr[-2000:]}")
    return int(m.group(1)), r.stdout, r.stderr, int(m.group(2)) / 1024.0, float(m.group(3))


def run_simcli(
    scene: str, threads: int, backend: str, cache: str, steps: int | None, sets: list[str] | None = None
) -> dict:
    env = dict(os.environ, SIMCLI_KERNEL_CACHE=cache)
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
            "--json",
            "--backend",
            backend,
            "--set",
            f"sim.threads={threads}",
        ]
        if steps:
            cmd += ["--set", f"sim.steps={steps}"]
        for kv in sets or []:
            cmd += ["--set", kv]
        rc, stdout, stderr, peak_mb, wall = _run(cmd, env, timeout=1800)
        if rc != 0:
            raise RuntimeError(f"simcli failed ({rc}): {stderr[-2000:]}")
        info = json.loads(stdout)
    t = info["timings"]
    tp = info["throughput"]
    # mesh scenes (FEM) count vertices, grid scenes (SF) cells: their "particle-substeps" are
    # vertex-substeps or cell-substeps
    counts = info.get("counts", {}).values()
    n = (
        info["particles"]
        or sum(int(c.get("vertices", 0)) for c in counts)
        or sum(int(c.get("cells", 0)) for c in counts)
    )
    sf = (info.get("solvers") or {}).get("sf") or {}
    res = sf.get("per_substep", {}).get("relative_residual") or []
    return {
        "particles": n,
        "time_to_first_step_s": t.get("time_to_first_step_s"),
        "steps_per_s": tp.get("steps_per_s"),
        "relative_residual": (sum(res) / len(res)) if res else None,
        "iterations": sf.get("iterations_mean"),
        "pressure_solver": sf.get("pressure_solver"),
        "process_wall_s": wall,
        "compile_s": t["compile_s"],
        "substeps_per_s": tp["substeps_per_s"],
        "particle_substeps_per_s": tp["particle_substeps_per_s"] or tp["substeps_per_s"] * n,
        "peak_mb": peak_mb,
        "backend": info["backend"],
        "threads": info.get("threads"),
    }


def genesis_python() -> str | None:
    cand = os.environ.get("GENESIS_PYTHON") or str(Path.home() / "genesis-venv" / "bin" / "python")
    return cand if Path(cand).exists() else None


def run_genesis(py: str, args: list[str], threads: int, cache: str | None, steps: int) -> dict:
    env = dict(os.environ, QD_NUM_THREADS=str(threads))
    if cache:
        env.update(QD_OFFLINE_CACHE_FILE_PATH=cache, GS_CACHE_FILE_PATH=cache)
    script = SHARED / "bench" / "genesis_bench.py"
    rc, stdout, stderr, peak_mb, wall = _run(
        [py, str(script), *args, "--steps", str(steps), "--max_s", "60"], env, timeout=1800
    )
    m = re.search(r"^RESULT (.*)$", stdout, re.M)
    if rc != 0 or not m:
        raise RuntimeError(f"genesis failed ({rc}): {stderr[-2000:]}")
    r = json.loads(m.group(1))
    n = r.get("n_particles") or r.get("n_vertices") or r.get("grid_cells") or 0
    first = r["import_s"] + r["gs_init_s"] + r["scene_setup_s"] + r["build_s"] + r["first_step_s"]
    return {
        "particles": n,
        "time_to_first_step_s": first,
        "process_wall_s": wall,
        "compile_s": r["build_s"],
        "steps_per_s": r.get("steps_per_s"),
        "substeps_per_s": r["substeps_per_s"],
        "particle_substeps_per_s": r["substeps_per_s"] * n,
        "peak_mb": peak_mb,
        "backend": "cpu",
        "threads": r.get("threads"),
    }


def genesis_sf_residual(py: str, args: list[str], threads: int, steps: int = 20) -> float:
    """Genesis's relative pressure residual after its Jacobi sweeps on the last of `steps` steps."""
    env = dict(os.environ, QD_NUM_THREADS=str(threads))
    script = _GENESIS_SF_RESIDUAL % str(SHARED / "bench" / "genesis_bench.py")
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as fh:
        fh.write(script)
    try:
        r = subprocess.run(
            [py, fh.name, *args, "--steps", str(steps), "--max_s", "120"],
            capture_output=True,
            text=True,
            env=env,
            timeout=1800,
            check=False,
        )
    finally:
        os.unlink(fh.name)
    m = re.search(r"^GENESIS_SF_RESIDUAL (.*)$", r.stdout, re.MULTILINE)
    if not m:
        raise RuntimeError(f"genesis residual failed ({r.returncode}): {r.stderr[-2000:]}")
    return float(json.loads(m.group(1))["relative_residual"])


def machine() -> str:
    cpu = platform.processor()
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    mem = ""
    try:
        import psutil

        mem = f", {psutil.virtual_memory().total / 2**30:.0f} GiB RAM"
    except ImportError:
        pass
    gpu = ""
    try:  # the GPU a cuda run used, when nvidia-smi is there
        r = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        if r.returncode == 0 and r.stdout.strip():
            gpu = f"; GPU {r.stdout.strip().splitlines()[0]}"
    except (OSError, subprocess.SubprocessError):
        pass
    return (
        f"{cpu}, {cores} cores available{mem}, {platform.system()} {platform.release()}, Python "
        f"{platform.python_version()}{gpu}"
    )


def fmt(x, nd=3):
    if x is None:
        return "-"
    if isinstance(x, float):
        if abs(x) >= 1e5:
            return f"{x / 1e6:.2f} M"
        return f"{x:.{nd}g}"
    return str(x)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "scenes",
        nargs="*",
        default=[s for s in SCENES if s not in GPU_SCENES],
        help=f"scene ids (default: all but the GPU-sized {', '.join(sorted(GPU_SCENES))})",
    )
    ap.add_argument("--threads", type=int, default=2, help="CPU threads for both simcli and Genesis")
    ap.add_argument("--backend", default="cpu", help="simcli backend (Genesis always runs on the CPU here)")
    ap.add_argument("--no-genesis", action="store_true", help="skip the Genesis runs")
    ap.add_argument("--steps", type=int, default=None, help="override the simcli scene's step count")
    ap.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="scene override passed to every simcli run (repeatable), e.g. sim.substeps=auto",
    )
    ap.add_argument(
        "--out", default=str(ROOT / "docs" / "PERFORMANCE.md"), help="Markdown report ('' = none)"
    )
    args = ap.parse_args()

    py = None if args.no_genesis else genesis_python()
    rows = []
    for sid in args.scenes:
        scene, gargs, gsteps = SCENES[sid]
        with tempfile.TemporaryDirectory() as cache:
            cold = run_simcli(scene, args.threads, args.backend, cache, args.steps, args.sets)
            warm = run_simcli(scene, args.threads, args.backend, cache, args.steps, args.sets)
        row = {"id": sid, "simcli_cold": cold, "simcli": warm}
        print(
            f"{sid} simcli: {json.dumps(warm)} (cold first step {cold['time_to_first_step_s']:.2f} s)",
            flush=True,
        )
        if py and gargs is not None and sid in GRID_SCENES:
            # equal pressure-solve accuracy: Genesis's residual after its 200 Jacobi sweeps, then simcli's
            # MGPCG stopped on the same relative residual (same scene, dt, threads; warm kernel cache)
            rel = genesis_sf_residual(py, gargs, args.threads)
            sets = [
                "solvers.sf.pressure_solver=mgpcg",
                "solvers.sf.tolerance=0",
                f"solvers.sf.relative_tolerance={rel}",
            ]
            with tempfile.TemporaryDirectory() as cache:
                mg_cold = run_simcli(scene, args.threads, args.backend, cache, args.steps, args.sets + sets)
                mg = run_simcli(scene, args.threads, args.backend, cache, args.steps, args.sets + sets)
            row.update(genesis_residual=rel, simcli_mgpcg=mg, simcli_mgpcg_cold=mg_cold)
            print(f"{sid} genesis relative residual {rel:.3g}; simcli mgpcg: {json.dumps(mg)}", flush=True)
        if py and gargs is not None:
            with tempfile.TemporaryDirectory() as gcache:
                gcold = run_genesis(py, gargs, args.threads, gcache, 20)
            gwarm = run_genesis(py, gargs, args.threads, None, gsteps)
            row.update(genesis_cold=gcold, genesis=gwarm)
            print(
                f"{sid} genesis: {json.dumps(gwarm)} (cold first step {gcold['time_to_first_step_s']:.2f} s)",
                flush=True,
            )
        rows.append(row)

    lines = [
        (
            "| scene | code | particles (vertices for meshes, cells for grids) | first step cold [s] | first "
            "step warm [s] | compile [s] | steps/s | substeps/s | particle- (cell-) substeps/s | peak memory "
            "[MB] | speed-up |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    notes = []
    for r in rows:
        for code in ("simcli", "simcli_mgpcg", "genesis"):
            if code not in r:
                continue
            w, c = r[code], r[code + "_cold"]
            ratio = ""
            if code.startswith("simcli") and "genesis" in r:
                ratio = (
                    f"{w['particle_substeps_per_s'] / r['genesis']['particle_substeps_per_s']:.2f}x "
                    "throughput, "
                    f"{r['genesis_cold']['time_to_first_step_s'] / c['time_to_first_step_s']:.1f}x faster "
                    "cold start"
                )
            label = {"simcli_mgpcg": "simcli (MGPCG, Genesis's residual)"}.get(code, code)
            lines.append(
                f"| {r['id']} | {label} | {w['particles']} | {fmt(c['time_to_first_step_s'])} | "
                f"{fmt(w['time_to_first_step_s'])} | {fmt(w['compile_s'])} | {fmt(w.get('steps_per_s'))} | "
                f"{fmt(w['substeps_per_s'])} | {fmt(w['particle_substeps_per_s'])} | {fmt(w['peak_mb'], 4)} "
                f"| {ratio} |"
            )
        if "genesis_residual" in r:
            s_, m_ = r["simcli"], r["simcli_mgpcg"]
            notes.append(
                f"{r['id']} pressure solve, relative residual ||r|| / ||div u*|| after the projection (mean "
                f"over the run): Genesis, 200 Jacobi sweeps: {r['genesis_residual']:.3g} (its last step); "
                f"simcli, {s_.get('pressure_solver')} {fmt(s_.get('iterations'))} sweeps: "
                f"{fmt(s_.get('relative_residual'))}; simcli, MGPCG stopped at Genesis's residual: "
                f"{fmt(m_.get('relative_residual'))} in {fmt(m_.get('iterations'))} iterations. "
                f"The two codes' residuals are of different equations: simcli's (MAC grid) is the "
                f"divergence left in the projected velocity; Genesis's is that of its compact-Laplacian "
                f"equation, while its collocated approximate projection leaves most of the divergence "
                f"in the velocity (docs/SF.md, Benchmark)."
            )
    # rows and notes of scenes not measured this time are kept from the last report, so that running one
    # family's scenes does not erase the others'
    measured = {r["id"] for r in rows}
    if args.out and Path(args.out).exists():
        for line in Path(args.out).read_text().splitlines():
            sid = line.split("|")[1].strip() if line.startswith("| ") else line.split(" ", 1)[0]
            if sid in SCENES and sid not in measured:
                if line.startswith("| "):
                    lines.append(line)
                elif " pressure solve, " in line:
                    notes.append(line)
    table = "\n".join(lines) + ("\n\n" + "\n\n".join(notes) if notes else "")
    print(table)
    if args.out:
        stamp = time.strftime("%Y-%m-%d")
        if args.backend == "cpu":
            intro = (
                "Regenerate with `python benchmarks/bench.py` (needs Genesis in ~/genesis-venv or "
                "$GENESIS_PYTHON for the side-by-side rows; see ../shared/bench/README.md).\n"
                "\n"
                "On a GPU (one H100, CUDA, the same scenes plus B2 at a million particles, and the "
                "validation set on CUDA): [PERFORMANCE_GPU.md](PERFORMANCE_GPU.md).\n"
                "\n"
                f"Measured {stamp} on: {machine()}. Threads: {args.threads} for both codes; simcli backend "
                f"{args.backend}, f32. Same scene, dt, substeps and thread count as Genesis's "
                "`genesis_bench.py`.\n"
                "\n"
            )
        else:
            intro = (
                "simcli on the GPU. Regenerate on a machine with one with `python benchmarks/bench.py "
                f"--backend {args.backend} --no-genesis --out docs/PERFORMANCE_GPU.md` (add `B2W1M B2D1M` "
                "for B2 at a million particles). Genesis was not run here: the CPU rows of PERFORMANCE.md "
                "are the side-by-side comparison.\n"
                "\n"
                f"Measured {stamp} on: {machine()}. simcli backend {args.backend}, f32; the same scene files "
                "as the CPU benchmarks.\n"
                "\n"
            )
        text = (
            "# Performance"
            + ("" if args.backend == "cpu" else f" on the GPU ({args.backend})")
            + "\n\n"
            + intro
            + "*First step*: from the start of the process's Python code (imports included) to the end of "
            "the first step; cold = empty kernel cache. *Compile*: simcli's first substep (kernel "
            "compilation); Genesis's `scene.build()`. *Substeps/s*: steady state, after warm-up. *Peak "
            "memory*: peak RSS of the process. `python benchmarks/bench.py B5` re-measures B5 only: the "
            "other scenes' rows are kept from the last report.\n"
            "\n" + table + "\n"
        )
        # hand-written paragraphs under the table (how a scene was run, caveats) are kept; the generated
        # pressure-solve notes are not (they were regenerated above)
        kept = _hand_notes(Path(args.out)) if Path(args.out).exists() else []
        link = (
            "MPM memory per particle and per node, thread scaling and what limits the speed: "
            "[PERFORMANCE_NOTES.md](PERFORMANCE_NOTES.md)."
        )
        if not any(k.startswith("MPM memory per particle") for k in kept):
            kept.append(link)
        text += "\n" + "\n\n".join(kept) + "\n"
        sph = ROOT / "docs" / "PERFORMANCE_SPH.md"
        main_report = Path(args.out).resolve() == (ROOT / "docs" / "PERFORMANCE.md").resolve()
        if sph.exists() and main_report:  # the section benchmarks/sph_vs_splishsplash.py writes
            text += "\n" + sph.read_text()
        elif Path(args.out).exists():  # hand-written sections (e.g. the GPU report's validation on CUDA)
            text += _later_sections(Path(args.out))
        Path(args.out).write_text(text)
        print(f"wrote {args.out}")


def _hand_notes(path: Path) -> list[str]:
    """The paragraphs between the report's table and its next section, less the generated ones."""
    lines = path.read_text().splitlines()
    i = 0
    while i < len(lines) and not lines[i].startswith("| scene |"):
        i += 1
    while i < len(lines) and lines[i].startswith("|"):
        i += 1
    block = []
    while i < len(lines) and not lines[i].startswith("## "):
        block.append(lines[i])
        i += 1
    paras = [p.strip() for p in "\n".join(block).split("\n\n") if p.strip()]
    return [p for p in paras if " pressure solve, relative residual" not in p.split("\n", 1)[0]]


def _later_sections(path: Path) -> str:
    """The report's "## " sections after the table, as they are (none are generated outside
    PERFORMANCE.md)."""
    lines = path.read_text().splitlines()
    for i, line in enumerate(lines):
        if line.startswith("## "):
            return "\n" + "\n".join(lines[i:]) + "\n"
    return ""


if __name__ == "__main__":
    main()
