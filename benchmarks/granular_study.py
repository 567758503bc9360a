"""Granular accuracy against resolution: the column collapses and the sand heap at three grids.

    PYTHONPATH=$PWD python benchmarks/granular_study.py [-o out/granular_study] [--write-docs]

Runs the verify cases mpm_sand_collapse_a0p5 / _a1 / _a2 / _a3 / _a4 / _a6 and mpm_sand_heap at refinement
levels
-1, 0, 1 (grid 64, 128, 256 cells per metre, particle spacing halved with the cell, substeps: auto,
which halves the step with the cell), plus level 0 with 6x the substeps (the time-step check), with
each transfer of ``--transfers`` (default: apic, the default transfer, and flip with flip_ratio 1),
and prints a markdown table of measured value, reference and error. ``--write-docs`` replaces the
table between the ``granular-study`` markers of docs/VALIDATION.md. About 50 minutes on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from simcli.scene.loader import load_scene  # noqa: E402
from simcli.verify.cases import default_root, load_case  # noqa: E402
from simcli.verify.run import run_case  # noqa: E402

CASES = [
    "mpm_sand_collapse_a0p5",
    "mpm_sand_collapse_a1",
    "mpm_sand_collapse_a2",
    "mpm_sand_collapse_a3",
    "mpm_sand_collapse_a4",
    "mpm_sand_collapse_a6",
    "mpm_sand_heap",
]
LEVELS = [-1, 0, 1]
BEGIN, END = "<!-- granular-study:begin -->", "<!-- granular-study:end -->"


def _value(msg: str) -> str:
    m = re.search(r"measured ([-+0-9.eE]+)", msg)
    return m.group(1) if m else "-"


TRANSFERS = {
    "apic": {},
    "flip": {"solvers.mpm.transfer": "flip", "solvers.mpm.flip_ratio": 1.0},
}


def study(out: Path, cases: list[str], transfers: list[str]) -> list[str]:
    rows = [
        "| case | transfer | grid [1/m] | substeps per 2 ms | measured | reference | error | tolerance "
        "| wall [s] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, tr in [(n, t) for n in cases for t in transfers]:
        case = load_case(default_root() / f"{name}.case.yaml")
        case = case.model_copy(update={"overrides": {**case.overrides, **TRANSFERS[tr]}})
        runs = [(lvl, case) for lvl in LEVELS]
        fine_dt = case.model_copy(update={"overrides": {**case.overrides, "sim.substeps": 96}})
        runs.append((0, fine_dt))
        for lvl, c in runs:
            r = run_case(c, lvl, out, judge=False)
            grid = int(round(128 * 2**lvl))
            sim = load_scene(c.scene_path, [], check=False).scene.sim
            steps = max(1, round(sim.duration / sim.dt))
            sub = (
                "96 (fixed)"
                if c is fine_dt
                else (str(round(r.substeps_total / steps)) if r.substeps_total else "auto")
            )
            if r.exit_code != 0 or r.error is None:
                rows.append(
                    f"| {name} | {tr} | {grid} | {sub} | failed: {r.message} | | | | {r.wall_s:.0f} |"
                )
                continue
            unit = " deg" if "heap" in name else ""
            err = f"{r.error:.1f} deg" if "heap" in name else f"{100 * r.error:.1f}%"
            tol = f"{case.tolerance:g} deg" if "heap" in name else f"{100 * case.tolerance:.0f}%"
            ref = case.reference.value
            rows.append(
                f"| {name} | {tr} | {grid} | {sub} | {float(_value(r.message)):.3g}{unit} | {ref:g}{unit} | "
                f"{err} "
                f"| {tol} | {r.wall_s:.0f} |"
            )
            print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", default="out/granular_study")
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated verify case names")
    ap.add_argument("--transfers", default="apic,flip", help="comma-separated: apic, flip (flip_ratio 1)")
    args = ap.parse_args()
    cases = [c.strip() for c in args.cases.split(",")]
    rows = study(Path(args.out), cases, [t.strip() for t in args.transfers.split(",")])
    table = "\n".join(rows)
    print(table)
    if args.write_docs:
        doc = ROOT / "docs" / "VALIDATION.md"
        text = doc.read_text()
        i, j = text.index(BEGIN), text.index(END)
        doc.write_text(text[: i + len(BEGIN)] + "\n" + table + "\n" + text[j:])


if __name__ == "__main__":
    main()
