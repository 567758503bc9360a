"""The SPH pair loops and FEM's per-vertex sums compile without gather instructions.

Taichi compiles with fast math for the host CPU; LLVM 15 then vectorises a loop over a neighbour list with
``llvm.masked.gather`` where its cost model calls gathers cheap (Intel Xeons), and there they made a DFSPH
iteration's passes 2.4x slower than scalar code (docs/SPH.md, Performance, session 26). Each such loop starts
with a never-taken exit (simcli/solvers/sph/neighbours.py, "Scalar pair loops"). This test compiles the SPH
dam break of the SPlisHSPlasH benchmark and B4 (explicit FEM) with Taichi's optimised-IR dump and checks that
no kernel gathers. On a CPU whose cost model never picks gathers (AMD) it passes either way; on an Intel
machine it catches a new pair loop written without the guard.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

DUMP = """
import sys
import taichi as ti
_init = ti.init
def init(*a, **k):
    k["print_kernel_llvm_ir_optimized"] = True
    k["offline_cache"] = False
    return _init(*a, **k)
ti.init = init
from simcli.cli import main
sys.argv = ["simcli"] + sys.argv[1:]
try:
    main()
except SystemExit as e:
    if e.code not in (0, None):
        raise
"""


def _gathering_kernels(tmp: Path, scene: str, *sets: str) -> list[str]:
    (tmp / "dump.py").write_text(DUMP)
    args = [sys.executable, str(tmp / "dump.py"), "run", str(ROOT / scene), "-o", str(tmp / "out")]
    for s in ("sim.threads=1",) + sets:
        args += ["--set", s]
    r = subprocess.run(args, cwd=tmp, capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    files = sorted(tmp.glob("taichi_kernel_cpu_llvm_ir_optimized_*.ll"))
    assert files, "Taichi wrote no IR dump"
    return [f.name for f in files if "llvm.masked.gather" in f.read_text()]


def test_sph_pair_loops_do_not_gather(tmp_path):
    bad = _gathering_kernels(tmp_path, "configs/bench/sph_dambreak_splishsplash.yaml", "sim.duration=0.1")
    assert not bad, f"SPH kernels vectorised with gathers: {bad} (add the pair loop's guard)"


def test_fem_vertex_sums_do_not_gather(tmp_path):
    bad = _gathering_kernels(tmp_path, "configs/bench/b4_explicit.yaml", "sim.steps=1")
    assert not bad, f"FEM kernels vectorised with gathers: {bad} (add the loop's guard)"
