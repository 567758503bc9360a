"""Work-precision studies: several options of one validation case on one plot.

A *variant* is a label plus ``key=value`` scene overrides (``--set`` syntax, values YAML-typed)
applied on top of a case's own overrides; a *study* runs one case at several resolutions
(``run_refinement``, the machinery of ``simcli verify --refine``) once per variant and overlays
the results: error against resolution and error against stepping wall time (compile excluded).
Studies are data (``benchmarks/work_precision.yaml``); ``benchmarks/work_precision.py`` runs them.

    mpm_transfers_sulsky:
      case: mpm_disk_sulsky_flip_energy     # a configs/validation case
      levels: 3
      refine: {solvers.mpm.grid_density: 2, solvers.mpm.particle_size: 0.5}   # replaces the case's
      overrides: {}                         # applied to every variant
      variants:
        APIC: {solvers.mpm.transfer: apic}
        pure FLIP: {solvers.mpm.transfer: flip, solvers.mpm.flip_ratio: 1.0}

The rows of a study are kept in a CSV (one row per variant and level); a later run of some
variants (``only``) replaces those variants' rows and keeps the others, so a new option is added to
a published plot without rerunning the old ones.
"""

from __future__ import annotations

import csv
import math
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simcli.errors import SceneError

CSV_COLUMNS = [
    "study",
    "variant",
    "level",
    "resolution",
    "x",
    "error",
    "order",
    "stepping_s",
    "compile_s",
    "time_s",
    "wall_s",
    "particles",
    "size",
    "substeps_total",
    "exit_code",
    "overrides",
    "message",
]


@dataclass
class Variant:
    label: str
    overrides: dict[str, Any] = field(default_factory=dict)


def parse_overrides(items: list[str], where: str = "variant") -> dict[str, Any]:
    """``['a.b=1', 'c=flip']`` -> ``{'a.b': 1, 'c': 'flip'}`` (values YAML-typed, as ``--set``)."""
    from simcli.scene.overrides import parse_set

    out: dict[str, Any] = {}
    for item in items:
        try:
            path, value = parse_set(item)
        except ValueError as e:
            raise SceneError([f"{where}: '{item}': {e}"]) from None
        out[".".join(str(p) for p in path)] = value
    return out


def parse_variant(spec: str) -> Variant:
    """``'LABEL: key=value key=value'`` (overrides separated by blanks, shell-quoted where a value
    has blanks); ``'LABEL'`` alone is the case as written."""
    label, sep, rest = spec.partition(":")
    label = label.strip()
    if not label:
        raise SceneError(
            [
                f"--variant '{spec}': no label; write 'LABEL: key=value ...', "
                "e.g. 'tet10: solvers.fem.element=tet10'"
            ]
        )
    items = shlex.split(rest) if sep else []
    return Variant(label, parse_overrides(items, where=f"--variant '{label}'"))


def variant_case(case, variant: Variant, overrides: dict | None = None, refine: dict | None = None):
    """A copy of ``case`` named ``case [label]`` with the study's and the variant's overrides on top of
    the case's own (later wins), and the study's refine factors (when given) instead of the case's."""
    c = case.model_copy(deep=True)
    c.overrides = {**case.overrides, **(overrides or {}), **variant.overrides}
    if refine is not None:
        c.refine = dict(refine)
    c.name = f"{case.name} [{variant.label}]"
    return c


def study_case(study: Study, base, variant: Variant):
    """``variant_case`` with the study's changes to the measurement (``measure_params``) and to the
    error metric (``error``: fields of the case's ``error``) applied."""
    from simcli.verify.cases import ErrorSpec, Measure

    c = variant_case(base, variant, study.overrides, study.refine)
    if study.measure_params:
        m = c.measure.model_dump()
        m["params"] = {**m["params"], **study.measure_params}
        c.measure = Measure(**m)
    if study.error:
        c.error = ErrorSpec(**{**c.error.model_dump(), **study.error})
    return c


def level_case(study: Study, case, level: int):
    """``case`` with the measure parameters named in ``study.refine_params`` scaled by factor**level
    (a length the measurement needs that follows the resolution, e.g. the particle spacing)."""
    from simcli.verify.cases import Measure

    if not study.refine_params or level == 0:
        return case
    c = case.model_copy(deep=True)
    m = c.measure.model_dump()
    for k, f in study.refine_params.items():
        m["params"][k] = m["params"][k] * f**level
    c.measure = Measure(**m)
    return c


def run_levels(study: Study, case, levels: int, out: Path, backend, reuse: bool):
    """``run_refinement`` (nothing judged) with the measure parameters following the levels."""
    from simcli.verify import run as vrun

    if not study.refine_params:
        rs = vrun.run_refinement(case, levels, out, backend, reuse=reuse)
        for r in rs:
            r.passed = None
        return rs
    rs = [
        vrun.run_case(level_case(study, case, k), k, out, backend, judge=False, reuse=reuse)
        for k in range(levels)
    ]
    ratio = vrun.refinement_ratio(case)
    for a, b in zip(rs, rs[1:]):
        if a.error and b.error and a.error > 0 and b.error > 0:
            b.order = math.log(a.error / b.error) / math.log(ratio)
    return rs


@dataclass
class Study:
    name: str
    case: str
    levels: int = 3
    refine: dict[str, float] | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    variants: list[Variant] = field(default_factory=list)
    title: str = ""
    error_label: str = "error"
    x_key: str | None = None  # the override whose value is the left panel's x (default: first refine key)
    x_label: str = ""
    plot: str | None = None  # repository-relative paths
    csv: str | None = None
    doc: str | None = None  # a Markdown file with <!-- wp:NAME --> ... <!-- /wp:NAME --> around the table
    note: str = ""
    measure_params: dict[str, Any] = field(default_factory=dict)  # on top of the case's measure.params
    refine_params: dict[str, float] = field(default_factory=dict)  # measure params scaled per level
    error: dict[str, Any] = field(default_factory=dict)  # fields of the case's error spec replaced
    time: str = "stepping"  # the cost plotted: "stepping" or "first_step" (see TIME_LABEL)
    repeat: int = 1  # runs of each variant and level; the fastest stepping time is kept
    refine_keys: list[str] = field(default_factory=list)  # filled in by run_study


_STUDY_KEYS = {
    "case",
    "levels",
    "refine",
    "overrides",
    "variants",
    "title",
    "error_label",
    "x_key",
    "x_label",
    "plot",
    "csv",
    "doc",
    "note",
    "repeat",
    "time",
    "measure_params",
    "refine_params",
    "error",
}


def load_studies(path: Path) -> dict[str, Study]:
    import yaml

    data = yaml.safe_load(Path(path).read_text()) or {}
    studies = {}
    for name, d in data.items():
        unknown = set(d) - _STUDY_KEYS
        if unknown:
            raise SceneError([f"{path}: study '{name}': unknown key(s) {', '.join(sorted(unknown))}"])
        if "case" not in d:
            raise SceneError([f"{path}: study '{name}': 'case' is required"])
        if d.get("time", "stepping") not in TIME_LABEL:
            raise SceneError([f"{path}: study '{name}': time: one of {', '.join(TIME_LABEL)}"])
        variants = [Variant(str(k), dict(v or {})) for k, v in (d.get("variants") or {}).items()]
        studies[name] = Study(
            name=name,
            case=d["case"],
            levels=int(d.get("levels", 3)),
            refine=d.get("refine"),
            overrides=dict(d.get("overrides") or {}),
            variants=variants,
            title=d.get("title", ""),
            error_label=d.get("error_label", "error"),
            x_key=d.get("x_key"),
            x_label=d.get("x_label", ""),
            plot=d.get("plot"),
            csv=d.get("csv"),
            doc=d.get("doc"),
            note=d.get("note", ""),
            repeat=int(d.get("repeat", 1)),
            time=str(d.get("time", "stepping")),
            measure_params=dict(d.get("measure_params") or {}),
            refine_params=dict(d.get("refine_params") or {}),
            error=dict(d.get("error") or {}),
        )
    return studies


def resolved_values(scene_path: Path, sets: list[str], keys: list[str]) -> dict[str, Any]:
    """The values ``keys`` (dotted) take in the resolved scene with ``sets`` applied (defaults filled
    in); a key the scene does not have is left out."""
    from simcli.scene.loader import load_scene
    from simcli.scene.models import resolved_scene_dict
    from simcli.scene.overrides import split_path

    loaded = load_scene(scene_path, sets, check=False)
    res = resolved_scene_dict(loaded.scene, loaded.name)
    out = {}
    for key in keys:
        cur: Any = res
        try:
            for p in split_path(key):
                cur = cur[p]
        except (KeyError, IndexError, TypeError):
            continue
        out[key] = cur
    return out


def _g(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def size_of(counts: dict) -> str:
    """``run.json``'s counts in words: '6456 particles', '1025 vertices / 3840 tets'."""
    parts = []
    for fam, c in (counts or {}).items():
        if not isinstance(c, dict):
            continue
        if "particles" in c:
            parts.append(f"{c['particles']} particles")
        elif "vertices" in c:
            cells = ", ".join(f"{v} {k}" for k, v in c.items() if k != "vertices")
            parts.append(f"{c['vertices']} vertices" + (f" / {cells}" if cells else ""))
        else:
            parts.append(f"{fam}: " + ", ".join(f"{v} {k}" for k, v in c.items()))
    return "; ".join(parts)


def _size(out_root: Path | None, scene_path: Path | None, level: int, sets: list[str], backend) -> str:
    """The size of the run ``run_case`` made for these sets (its folder is named by their hash)."""
    import hashlib
    import json

    if out_root is None or scene_path is None:
        return ""
    key = hashlib.sha1(json.dumps([str(scene_path), sets, backend]).encode()).hexdigest()[:10]
    try:
        info = json.loads(
            (Path(out_root) / "runs" / f"{scene_path.stem}-L{level}-{key}" / "run.json").read_text()
        )
    except (OSError, ValueError):
        return ""
    return size_of(info.get("counts") or {})


def result_rows(
    study: Study,
    label: str,
    results,
    x_key: str | None,
    scene_path: Path | None = None,
    out_root: Path | None = None,
    backend: str | None = None,
) -> list[dict]:
    """One row per result; the resolution is written from the resolved scene (so level 0 names its
    values too) when ``scene_path`` is given, the size from the run's run.json when ``out_root`` is."""
    rows = []
    for r in results:
        keys = list(dict.fromkeys(study.refine_keys + ([x_key] if x_key else [])))
        resolution, x = r.resolution, None
        if scene_path is not None:
            try:
                vals = resolved_values(scene_path, r.overrides, keys)
            except Exception:  # a scene that does not load reports its failure in the run's message
                vals = {}
            if study.refine_keys:
                shown = [k for k in study.refine_keys if k in vals]
                if shown:
                    resolution = ", ".join(f"{k.split('.')[-1]}={_g(vals[k])}" for k in shown)
            if x_key in vals:
                try:
                    x = float(vals[x_key])
                except (TypeError, ValueError):
                    x = None
        rows.append(
            {
                "study": study.name,
                "variant": label,
                "level": r.level,
                "resolution": resolution,
                "x": x,
                "error": r.error,
                "order": r.order,
                "stepping_s": r.stepping_s,
                "compile_s": r.compile_s,
                "time_s": _time_of(study, r.stepping_s, r.compile_s),
                "wall_s": r.wall_s,
                "particles": r.particles,
                "size": _size(out_root, scene_path, r.level, r.overrides, backend),
                "substeps_total": r.substeps_total,
                "exit_code": r.exit_code,
                "overrides": " ".join(r.overrides),
                "message": r.message,
            }
        )
    return rows


TIME_LABEL = {
    "stepping": ("stepping [s]", "stepping wall time [s] (compile excluded"),
    "first_step": (
        "first step + stepping [s]",
        "wall time of all steps [s] (kernels cached",
    ),
}
"""Study ``time``: ``stepping`` is run.json's stepping_s (compilation excluded; simcli times the first
step with the compilation, so a run of a few costly steps, e.g. a static solve, hides its work there);
``first_step`` adds compile_s (the first step, and loading the cached kernels: about 0.5-1 s)."""


def _time_of(study: Study, stepping: float | None, compile_: float | None) -> float | None:
    if study.time == "first_step":
        return None if stepping is None or compile_ is None else stepping + compile_
    return stepping


def time_of_row(r: dict) -> float | None:
    """The time a row is plotted at: its time_s, or (rows written before time_s existed) stepping_s."""
    t = r.get("time_s")
    return t if t is not None else r.get("stepping_s")


def _inf(v):
    return math.inf if v is None else v


def fastest_of(reps: list[list[dict]]) -> list[dict]:
    """Combine repetitions of the same rows (same variants and levels, in the same order): the first
    repetition's row with the fastest stepping time of all; a repetition whose error differs from the
    first's (runs are deterministic on one machine) is named in the message."""
    out = []
    for group in zip(*reps):
        row = dict(group[0])
        fastest = min(group, key=lambda g: _inf(time_of_row(g)))
        for k in ("stepping_s", "compile_s", "time_s"):
            if k in fastest:
                row[k] = fastest[k]
        if len(group) > 1:
            row["message"] = (row["message"] + f"; fastest of {len(group)} runs").lstrip("; ")
            errs = {g["error"] for g in group}
            if len(errs) > 1:
                row["message"] += f" (errors differ between runs: {sorted(e for e in errs if e is not None)})"
        out.append(row)
    return out


def run_study(
    study: Study,
    cases: dict,
    out: Path,
    backend: str | None = None,
    reuse: bool = False,
    only: list[str] | None = None,
    levels: int | None = None,
    echo=print,
    repeat: int = 1,
) -> list[dict]:
    """Run every variant of ``study`` (or those labelled in ``only``) at ``levels`` resolutions;
    ``repeat`` > 1 runs the whole set that many times, the variants alternating, and keeps each row's
    fastest stepping time (the machine's load drifts; the fastest run is the least disturbed)."""
    from simcli.verify import run as vrun

    if study.case not in cases:
        raise SceneError([f"study '{study.name}': unknown case '{study.case}'"])
    base = cases[study.case]
    labels = [v.label for v in study.variants]
    if only:
        missing = [o for o in only if o not in labels]
        if missing:
            raise SceneError(
                [f"study '{study.name}': no variant {', '.join(missing)} (has {', '.join(labels)})"]
            )
    reps: list[list[dict]] = []
    for k in range(max(1, repeat)):
        if k > 0:
            vrun._DONE.clear()  # verify's in-process cache would hand back the first repetition's runs
        rows: list[dict] = []
        for v in study.variants:
            if only and v.label not in only:
                continue
            case = study_case(study, base, v)
            x_key = study.x_key or next(iter(case.refine), None)
            echo(f"work-precision: {study.name}: {v.label} (run {k + 1} of {max(1, repeat)}) ...")
            study.refine_keys = list(case.refine)
            where = out if k == 0 else out / f"repeat{k}"
            rs = run_levels(study, case, levels or study.levels, where, backend, reuse)
            vrows = result_rows(study, v.label, rs, x_key, case.scene_path, where, backend)
            for r, row in zip(rs, vrows):
                err = "-" if r.error is None else f"{r.error:.4g}"
                echo(
                    f"  level {r.level} ({row['resolution']}): error {err}, "
                    f"stepping {r.stepping_s} s {r.message}"
                )
            rows += vrows
        reps.append(rows)
    return fastest_of(reps) if len(reps) > 1 else reps[0]


def merge_rows(old: list[dict], new: list[dict]) -> list[dict]:
    """The rows of ``new``, and those of ``old`` whose variant ``new`` does not have; variants in the
    order they first appear (old first), levels in order."""
    fresh = {r["variant"] for r in new}
    kept = [r for r in old if r["variant"] not in fresh]
    order: list[str] = []
    for r in kept + new:
        if r["variant"] not in order:
            order.append(r["variant"])
    rows = kept + new
    return sorted(rows, key=lambda r: (order.index(r["variant"]), int(r["level"])))


def _num(v, kind=float):
    if v is None or v == "" or v == "None":
        return None
    try:
        return kind(v)
    except ValueError:
        return None


def read_rows(path: Path) -> list[dict]:
    if not Path(path).is_file():
        return []
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r["level"] = _num(r.get("level"), int)
        r["exit_code"] = _num(r.get("exit_code"), int)
        for k in ("x", "error", "order", "stepping_s", "compile_s", "time_s", "wall_s"):
            r[k] = _num(r.get(k))
        for k in ("particles", "substeps_total"):
            r[k] = _num(r.get(k), int)
    return rows


def write_rows(rows: list[dict], path: Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in CSV_COLUMNS})


def _f(v, fmt="{:.3g}") -> str:
    return "-" if v is None else fmt.format(v)


def markdown(rows: list[dict], study: Study) -> str:
    head = [
        "variant",
        "level",
        "resolution",
        study.error_label,
        "order",
        TIME_LABEL[study.time][0],
        "size",
        "steps",
    ]
    lines = ["|" + "---|" * len(head)]
    for r in rows:
        err = _f(r["error"], "{:.4g}")
        if r.get("exit_code"):
            err = f"run failed ({r['exit_code']})"
        cells = [
            r["variant"],
            str(r["level"]),
            str(r["resolution"]),
            err,
            _f(r["order"], "{:.2f}"),
            _f(time_of_row(r), "{:.2f}"),
            r.get("size") or _f(r.get("particles") or None, "{:d} particles"),
            _f(r.get("substeps_total"), "{:d}"),
        ]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "| " + " | ".join(h.replace("|", "\\|") for h in head) + " |\n" + "\n".join(lines) + "\n"


def update_doc(doc: Path, name: str, text: str) -> bool:
    """Replace what lies between ``<!-- wp:NAME -->`` and ``<!-- /wp:NAME -->`` in ``doc`` by ``text``;
    False (and nothing written) when the markers are absent."""
    doc = Path(doc)
    if not doc.is_file():
        return False
    src = doc.read_text()
    a, b = f"<!-- wp:{name} -->", f"<!-- /wp:{name} -->"
    i, j = src.find(a), src.find(b)
    if i < 0 or j < i:
        return False
    doc.write_text(src[: i + len(a)] + "\n" + text.rstrip("\n") + "\n" + src[j:])
    return True


def _tick(x: float) -> str:
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.3g}"


def plot(rows: list[dict], path: Path, study: Study) -> Path | None:
    """Two panels: error against the resolution key (log-log) and against stepping wall time, one line
    per variant, each point labelled with its resolution."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    by: dict[str, list[dict]] = {}
    for r in rows:
        if r["error"] is not None and r["error"] > 0 and math.isfinite(r["error"]):
            by.setdefault(r["variant"], []).append(r)
    if not by:
        return None
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11.5, 4.4))
    markers = "osD^v<>ph*"
    for i, (label, rs) in enumerate(by.items()):
        rs = sorted(rs, key=lambda r: r["level"])
        m = markers[i % len(markers)] + "-"
        err = [r["error"] for r in rs]
        xs = [r["x"] if r["x"] is not None else r["level"] for r in rs]
        if all(r["x"] is not None for r in rs):
            ax1.loglog(xs, err, m, label=label)
        else:
            ax1.semilogy(xs, err, m, label=label)
        wt = [time_of_row(r) if time_of_row(r) is not None else r["wall_s"] for r in rs]
        (line,) = ax2.loglog(wt, err, m, label=label)
        for r, x, y in zip(rs, wt, err):
            if r["x"] is not None:
                short = _tick(r["x"])
            else:
                short = ", ".join(p.split("=")[-1] for p in str(r["resolution"]).split(", "))
            ax2.annotate(
                short, (x, y), fontsize=7, textcoords="offset points", xytext=(4, 3), color=line.get_color()
            )
    xs_all = sorted({r["x"] for rs in by.values() for r in rs if r["x"] is not None})
    if xs_all:
        from matplotlib.ticker import FixedLocator, NullLocator

        ax1.xaxis.set_major_locator(FixedLocator(xs_all))
        ax1.xaxis.set_minor_locator(NullLocator())
        ax1.set_xticklabels([_tick(x) for x in xs_all])
    ax1.set_xlabel(study.x_label or "refinement level")
    ax1.set_ylabel(study.error_label)
    ax1.set_title("convergence")
    ax2.set_xlabel(TIME_LABEL[study.time][1] + "; 2-core CPU under shared load)")
    ax2.set_ylabel(study.error_label)
    ax2.set_title("work-precision (lower left is better)")
    errs = [r["error"] for rs in by.values() for r in rs]
    lo, hi = 10 ** math.floor(math.log10(min(errs))), 10 ** math.ceil(math.log10(max(errs)))
    for ax in (ax1, ax2):
        ax.set_ylim(lo, hi if hi > lo else lo * 10)  # whole decades, so every panel has labelled ticks
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    if study.title:
        fig.suptitle(study.title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
