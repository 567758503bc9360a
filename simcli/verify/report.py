"""Verification report: Markdown and CSV tables, and work-precision / convergence plots."""

from __future__ import annotations

import csv
from pathlib import Path

from simcli.verify.run import Result

COLUMNS = [
    "case",
    "level",
    "resolution",
    "error",
    "tolerance",
    "passed",
    "kind",
    "order",
    "wall_s",
    "stepping_s",
    "compile_s",
    "particles",
    "particle_substeps_per_s",
    "exit_code",
    "message",
]


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "pass" if v else "FAIL"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v).replace("|", "/")


def markdown_table(results: list[Result]) -> str:
    head = [
        "case",
        "level",
        "resolution",
        "error",
        "tolerance",
        "result",
        "order",
        "wall [s]",
        "stepping [s]",
        "particles",
        "particle-substeps/s",
        "note",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        result = r.status
        cells = [
            r.case,
            str(r.level),
            r.resolution,
            _fmt(r.error),
            _fmt(r.tolerance),
            result,
            _fmt(r.order),
            _fmt(r.wall_s),
            _fmt(r.stepping_s),
            _fmt(r.particles),
            _fmt(r.particle_substeps_per_s),
            _fmt(r.message),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_csv(results: list[Result], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in results:
            w.writerow(r.row())


def plot_refinement(results: list[Result], path: Path) -> Path | None:
    """Two panels per case: error vs resolution level (with observed order) and the
    work-precision diagram (log error against log stepping wall time, compile excluded)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    by_case: dict[str, list[Result]] = {}
    for r in results:
        if r.error is not None and r.error > 0:
            by_case.setdefault(r.case, []).append(r)
    by_case = {k: v for k, v in by_case.items() if len(v) >= 2}
    if not by_case:
        return None
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name, rs in by_case.items():
        lv = [r.level for r in rs]
        err = [r.error for r in rs]
        ax1.semilogy(lv, err, "o-", label=name)
        wt = [r.stepping_s or r.wall_s for r in rs]
        ax2.loglog(wt, err, "o-", label=name)
        for r, x, y in zip(rs, wt, err):
            ax2.annotate(r.resolution, (x, y), fontsize=7, textcoords="offset points", xytext=(3, 3))
    ax1.set_xlabel("refinement level (resolution x2 per level)")
    ax1.set_ylabel("error")
    ax1.set_title("convergence")
    ax2.set_xlabel("stepping wall time [s] (compile excluded)")
    ax2.set_ylabel("error")
    ax2.set_title("work-precision")
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
