"""Memory and disk estimates against measured peaks: regenerates the table of docs/PERFORMANCE.md ("Memory").

For each family, scenes of three sizes (about 10x apart) run a few steps with ``simcli run`` under
``/usr/bin/time -v``; the table compares the estimate of simcli.scene.resources (what `validate` and `run`
refuse with) with the measured peak resident set size, and the estimated output size with the bytes the
run wrote. Runs are one at a time (the machine is shared).

    PYTHONPATH=$PWD python benchmarks/memory_estimates.py            # every family, every size
    PYTHONPATH=$PWD python benchmarks/memory_estimates.py MPM SF     # some families
    PYTHONPATH=$PWD python benchmarks/memory_estimates.py --small    # the smallest size only (quick)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

STEPS = 3  # steps per run: build, compile, a few substeps, four frames written


def _sim(dt: float, substeps: int = 1) -> str:
    return f"sim: {{dim: 3, dt: {dt}, substeps: {substeps}, steps: {STEPS}}}\n"


def mpm(gd: int) -> str:
    return (
        "version: 1\nname: mem_mpm\n" + _sim(1.0e-4) + "domain: {lower: [0, 0, 0], upper: [0.8, 0.3, 0.5]}\n"
        f"solvers:\n  mpm: {{grid_density: {gd}}}\n"
        "entities:\n  - name: water\n"
        "    material: {type: MPM.Liquid, E: 1.0e6, nu: 0.2, rho: 1000}\n"
        "    morph: {type: Box, lower: [0, 0, 0], upper: [0.2, 0.3, 0.35]}\n"
        "output: {every: 1, fields: [position, velocity, pressure]}\n"
    )


def sph(h: float) -> str:
    return (
        "version: 1\nname: mem_sph\n"
        + _sim(1.0e-4)
        + "domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 1.0], boundary: {type: slip}}\n"
        f"solvers:\n  sph: {{particle_size: {h}, pressure_solver: DFSPH}}\n"
        "entities:\n  - name: water\n"
        "    material: {type: SPH.Liquid, rho: 1000, mu: 0.001}\n"
        "    morph: {type: Box, center: [-0.3, 0, 0.25], size: [0.36, 0.9, 0.46]}\n"
        "output: {every: 1, fields: [position, velocity, density, pressure]}\n"
    )


def fem(res: int) -> str:
    return (
        "version: 1\nname: mem_fem\n"
        + _sim(1.0e-5)
        + f"solvers:\n  fem: {{integrator: explicit, resolution: {res}}}\n"
        "entities:\n  - name: block\n"
        "    material: {type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000, model: stable_neohookean}\n"
        "    morph: {type: Box, lower: [-0.1, -0.1, 0.2], upper: [0.1, 0.1, 0.4]}\n"
        "output: {every: 1}\n"
    )


def pbd(res: int) -> str:
    return (
        "version: 1\nname: mem_pbd\n" + _sim(4.0e-4) + "domain: {lower: [-1, -1, 0], upper: [1, 1, 1.5]}\n"
        "solvers:\n  pbd: {particle_size: 0.001}\n"
        "entities:\n  - name: cloth\n"
        "    material: {type: PBD.Cloth, rho: 0.2}\n"
        f"    morph: {{type: Rectangle, center: [0, 0, 0.8], size: [1.0, 1.0], resolution: {res}}}\n"
        "output: {every: 1}\n"
    )


def pbd_liquid(h: float) -> str:
    return (
        "version: 1\nname: mem_pbf\n"
        + _sim(2.0e-4)
        + "domain: {lower: [-0.25, -0.1, 0], upper: [0.25, 0.1, 0.6], boundary: {type: slip}}\n"
        f"solvers:\n  pbd: {{particle_size: {h}}}\n"
        "entities:\n  - name: water\n"
        "    material: {type: PBD.Liquid, rho: 1000}\n"
        "    morph: {type: Box, lower: [-0.2, -0.09, 0.05], upper: [0.2, 0.09, 0.5]}\n"
        "output: {every: 1, fields: [position, velocity, density]}\n"
    )


def sf(res: int) -> str:
    return (
        "version: 1\nname: mem_sf\n"
        + _sim(0.01)
        + "domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 1.0], boundary: {type: slip}, "
        "faces: {z+: {type: open}}}\n"
        f"solvers:\n  sf: {{resolution: {res}, advection: maccormack, pressure_solver: mgpcg}}\n"
        "entities:\n  - name: smoke\n"
        "    material: {type: SF.Smoke, vorticity_confinement: 0.3}\n"
        "    jets:\n      - {position: [0, 0, 0.1], radius: 0.1, velocity: [0, 0, 1], density_rate: 5}\n"
        "output: {every: 1}\n"
    )


def mixed(gd: int) -> str:
    """MPM liquid and an FEM block in one scene: two families' kernels compiled in one process."""
    return (
        "version: 1\nname: mem_mixed\n"
        + _sim(1.0e-5)
        + "domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 1.0]}\n"
        f"solvers:\n  mpm: {{grid_density: {gd}}}\n  fem: {{integrator: explicit, resolution: {gd}}}\n"
        "entities:\n  - name: water\n"
        "    material: {type: MPM.Liquid, E: 1.0e6, nu: 0.2, rho: 1000}\n"
        "    morph: {type: Box, lower: [0.1, 0.1, 0], upper: [0.3, 0.4, 0.35]}\n"
        "  - name: block\n"
        "    material: {type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000}\n"
        "    morph: {type: Box, lower: [-0.3, -0.3, 0.2], upper: [-0.1, -0.1, 0.4]}\n"
        "output: {every: 1}\n"
    )


def mpm_f64(gd: int) -> str:
    return mpm(gd).replace("sim: {dim: 3,", "sim: {dim: 3, precision: f64,")


def mpm_checkpoint(gd: int) -> str:
    """A checkpoint at step 2: the solver state's numpy copy adds to the peak."""
    return mpm(gd).replace("output: {every: 1,", "checkpoint: {every: 2}\noutput: {every: 1,")


def sph_2d(h: float) -> str:
    return (
        "version: 1\nname: mem_sph2d\nsim: {dim: 2, dt: 1.0e-4, substeps: 1, steps: 3}\n"
        "domain: {lower: [0, 0], upper: [4, 2], boundary: {type: slip}}\n"
        f"solvers:\n  sph: {{particle_size: {h}, pressure_solver: DFSPH}}\n"
        "entities:\n  - name: water\n"
        "    material: {type: SPH.Liquid, rho: 1000, mu: 0.001}\n"
        "    morph: {type: Box, lower: [0, 0], upper: [1.5, 1.5]}\n"
        "output: {every: 1}\n"
    )


# family -> (scene maker, the sizes (three about 10x apart; MPM a fourth at 5 M particles), what the size is)
CASES = {
    "MPM": (mpm, [100, 180, 320, 400], "grid_density"),
    "SPH": (sph, [0.02, 0.01, 0.0066], "particle_size"),
    "FEM": (fem, [100, 200, 300], "resolution"),
    "PBD": (pbd, [100, 316, 1000], "Rectangle resolution"),
    "PBF": (pbd_liquid, [0.01, 0.005, 0.0033], "particle_size"),
    "SF": (sf, [32, 64, 128], "resolution"),
    "MPM+FEM": (mixed, [100], "grid_density and resolution"),
    "MPM f64": (mpm_f64, [180], "grid_density"),
    "MPM checkpoint": (mpm_checkpoint, [320], "grid_density"),
    "SPH 2D": (sph_2d, [0.002], "particle_size"),
}


def _max_rss_bytes(stderr: str) -> int:
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", stderr)
    return int(m.group(1)) * 1024 if m else 0


def _du(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def estimate(family: str, size, d: Path):
    """(memory estimate, disk estimate, scene file) of a case, from the current code."""
    from simcli.scene.loader import load_scene
    from simcli.scene.resources import estimate_disk, estimate_memory

    d.mkdir(parents=True, exist_ok=True)
    scene = d / "scene.yaml"
    scene.write_text(CASES[family][0](size))
    loaded = load_scene(scene)
    est = estimate_memory(loaded.scene, loaded.scene_dir)
    return est, estimate_disk(loaded.scene, est), scene


def measure(family: str, size, work: Path) -> dict:
    what = CASES[family][2]
    d = work / f"{family}_{size}"
    shutil.rmtree(d, ignore_errors=True)
    est, disk, scene = estimate(family, size, d)
    out = d / "out"
    # an empty kernel cache: the first run of a scene compiles its kernels with LLVM, whose memory adds to
    # the peak (100-300 MB); a second run with the cache filled peaks lower. The estimate is for the first.
    cache = d / "kernel_cache"
    env = dict(os.environ, PYTHONPATH=str(ROOT), SIMCLI_KERNEL_CACHE=str(cache))
    t0 = time.perf_counter()
    p = subprocess.run(
        ["/usr/bin/time", "-v", sys.executable, "-m", "simcli", "run", str(scene), "-o", str(out), "-q"],
        capture_output=True,
        text=True,
        env=env,
    )
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        print(p.stderr[-3000:], file=sys.stderr)
    rss = _max_rss_bytes(p.stderr)
    wrote = _du(out)  # checkpoints included
    row = {
        "family": family,
        "size_value": size,
        "size": f"{what} {size}",
        "elements": est.elements_text(),
        "estimate_mb": est.total / 2**20,
        "measured_mb": rss / 2**20,
        "ratio": est.total / rss if rss else float("nan"),
        "disk_estimate_mb": disk / 2**20,
        "disk_measured_mb": wrote / 2**20,
        "wall_s": wall,
        "exit": p.returncode,
    }
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(cache, ignore_errors=True)
    return row


def table(rows: list[dict]) -> str:
    head = (
        "| family | size | elements | estimate MB | measured peak MB | estimate / measured | "
        "output est. MB | output written MB |\n|---|---|---|---:|---:|---:|---:|---:|\n"
    )
    body = "".join(
        f"| {r['family']} | {r['size']} | {r['elements']} | {r['estimate_mb']:,.0f} | "
        f"{r['measured_mb']:,.0f} | "
        f"{r['ratio']:.2f} | {r['disk_estimate_mb']:,.1f} | {r['disk_measured_mb']:,.1f} |\n"
        for r in rows
    )
    return head + body


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("families", nargs="*", default=list(CASES))
    ap.add_argument("--small", action="store_true", help="only the smallest size of each family")
    ap.add_argument("--sizes", default=None, help="comma-separated size indices (0, 1, 2, ...)")
    ap.add_argument("--work", default="/tmp/simcli_memory_bench", type=Path)
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    ap.add_argument(
        "--retable",
        nargs="+",
        type=Path,
        default=None,
        help="no runs: the table of these JSON files' measurements with the current code's estimates",
    )
    a = ap.parse_args()
    idx = [0] if a.small else [int(i) for i in a.sizes.split(",")] if a.sizes else None
    rows = []
    if a.retable:
        for f in a.retable:
            for r in json.loads(f.read_text()):
                size = r.get("size_value")
                if size is None:  # rows written before size_value was stored: the last word of size
                    last = r["size"].split()[-1]
                    size = float(last) if "." in last else int(last)
                est, disk, _ = estimate(r["family"], size, a.work / "retable")
                rss = r["measured_mb"] * 2**20
                r.update(
                    elements=est.elements_text(),
                    estimate_mb=est.total / 2**20,
                    ratio=est.total / rss,
                    disk_estimate_mb=disk / 2**20,
                )
                rows.append(r)
        print(table(rows))
        return
    for fam in a.families:
        for i in idx if idx is not None else range(len(CASES[fam][1])):
            size = CASES[fam][1][i]
            r = measure(fam, size, a.work)
            rows.append(r)
            print(json.dumps(r), file=sys.stderr, flush=True)
    print(
        f"machine: {platform.node()} {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d')}"
    )
    print(table(rows))
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
