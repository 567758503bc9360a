"""Run validation cases (optionally at several resolutions) and measure their errors."""

from __future__ import annotations

import hashlib
import json
import math
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from simcli.verify.cases import Case
from simcli.verify.measure import run_measurement
from simcli.verify.reference import compute_error

_DONE: dict[str, tuple[int, str, float, Path]] = {}  # runs made by this process, by scene+overrides


@dataclass
class Result:
    case: str
    level: int
    resolution: str
    error: float | None
    tolerance: float
    passed: bool | None  # None: not judged at this level (coarser levels of a refinement)
    wall_s: float
    stepping_s: float | None
    compile_s: float | None
    particles: int | None
    particle_substeps_per_s: float | None
    substeps_total: int | None
    exit_code: int
    message: str = ""
    order: float | None = None
    overrides: list[str] = field(default_factory=list)
    kind: str = "validation"  # the case's kind: a "measurement" is shown, not judged

    def row(self) -> dict:
        return asdict(self)

    @property
    def status(self) -> str:
        """pass, FAIL, measured (a measurement case that ran and measured a finite value), run failed
        (N) (not judged: a coarser level), or (coarser level)."""
        if self.passed is None:
            return f"run failed ({self.exit_code})" if self.exit_code != 0 else "(coarser level)"
        if not self.passed:
            return "FAIL"
        return "measured" if self.kind == "measurement" else "pass"


def level_overrides(case: Case, level: int) -> list[str]:
    """--set strings for refinement ``level``: each refine key scaled by factor**level."""
    from simcli.scene.loader import load_scene
    from simcli.scene.models import resolved_scene_dict
    from simcli.scene.overrides import split_path

    sets = [f"{k}={json.dumps(v)}" for k, v in case.overrides.items()]
    if level == 0 or not case.refine:
        return sets
    loaded = load_scene(case.scene_path, sets, check=False)
    res = resolved_scene_dict(loaded.scene, loaded.name)
    for key, factor in case.refine.items():
        cur = res
        for p in split_path(key):
            cur = cur[p]
        val = cur * factor**level
        if isinstance(cur, int) and not isinstance(cur, bool):
            val = int(round(val))
        sets.append(f"{key}={val!r}")
    return sets


def _resolution(case: Case, sets: list[str]) -> str:
    keys = list(case.refine) or []
    vals = {s.split("=", 1)[0]: s.split("=", 1)[1] for s in sets}
    return ", ".join(f"{k.split('.')[-1]}={vals[k]}" for k in keys if k in vals) or "base"


def _reusable(case: Case, sets: list[str], out: Path) -> float | None:
    """Wall time of a finished run in ``out`` made from exactly this scene (its resolved
    scene.yaml equals the case's, overrides applied), else None."""
    import yaml

    from simcli.scene.loader import load_scene
    from simcli.scene.models import resolved_scene_dict

    try:
        info = json.loads((out / "run.json").read_text())
        if info.get("status") != "done":
            return None
        old = yaml.safe_load((out / "scene.yaml").read_text())
        loaded = load_scene(case.scene_path, sets, check=False)
        new = resolved_scene_dict(loaded.scene, loaded.name)
        new["output"]["dir"] = old["output"]["dir"]
        if json.dumps(old, sort_keys=True) != json.dumps(new, sort_keys=True):
            return None
        return float(info.get("loop_wall_s") or info["timings"]["stepping_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def run_case(
    case: Case,
    level: int,
    out_root: Path,
    backend: str | None = None,
    judge: bool = True,
    quiet: bool = True,
    reuse: bool = False,
) -> Result:
    sets = level_overrides(case, level)
    # cases that measure different things on the same scene and resolution share one run
    key = hashlib.sha1(json.dumps([str(case.scene_path), sets, backend]).encode()).hexdigest()[:10]
    out = out_root / "runs" / f"{case.scene_path.stem}-L{level}-{key}"
    if key in _DONE:
        # the same run (another case on this scene, or a level a case without refine factors repeats):
        # read it where it was made
        code, stderr, wall, out = _DONE[key]
    elif reuse and (reused := _reusable(case, sets, out)) is not None:
        code, stderr, wall = 0, "", reused
        _DONE[key] = (code, stderr, wall, out)
    else:
        # --overwrite: the folder is this case's own, a previous `verify` left its run there
        cmd = [
            sys.executable,
            "-m",
            "simcli",
            "run",
            str(case.scene_path),
            "-o",
            str(out),
            "--quiet",
            "--overwrite",
        ]
        for s in sets:
            cmd += ["--set", s]
        if backend:
            cmd += ["--backend", backend]
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=case.timeout_s)
            code, stderr = proc.returncode, proc.stderr
        except subprocess.TimeoutExpired:
            code, stderr = 124, f"timed out after {case.timeout_s} s"
        wall = time.perf_counter() - t0
        _DONE[key] = (code, stderr, wall, out)
    info = {}
    try:
        info = json.loads((out / "run.json").read_text())
    except (OSError, ValueError):
        pass
    t = info.get("timings", {})
    tp = info.get("throughput", {})
    res = Result(
        case=case.name,
        level=level,
        resolution=_resolution(case, sets),
        error=None,
        tolerance=case.tolerance,
        passed=False if judge else None,
        wall_s=round(wall, 3),
        stepping_s=t.get("stepping_s"),
        compile_s=t.get("compile_s"),
        particles=info.get("particles"),
        particle_substeps_per_s=tp.get("particle_substeps_per_s"),
        substeps_total=(info.get("substeps") or {}).get("total"),
        exit_code=code,
        overrides=sets,
        kind=case.kind,
    )
    if code != 0:
        res.message = f"run failed (exit {code}): {stderr.strip().splitlines()[-1] if stderr.strip() else ''}"
        return res
    try:
        m = case.measure
        params = dict(m.params)
        if m.quantity == "collider_penetration":  # Mesh colliders' files are relative to the scene
            params.setdefault("scene_dir", str(case.scene_path.parent))
        tt, vals = run_measurement(out / "sim.h5", m.quantity, m.entity, m.axis, params)
        e = compute_error(case, tt, vals)
    except Exception as ex:  # a broken measurement is a failed case, reported, not a crash
        res.message = f"measurement failed: {type(ex).__name__}: {ex}"
        return res
    res.error = e["error"]
    where = {
        "max_abs": " (worst point)",
        "max_rel": " (worst point)",
        "final_abs": " (final)",
        "final_rel": " (final)",
        "rms": " (mean)",
        "rms_rel": " (mean)",
        "mean_abs": " (mean)",
        "mean_rel": " (mean)",
    }.get(case.error.metric, "")
    res.message = f"measured {e['measured']:.6g}, reference {e['reference']:.6g}{where}"
    if judge:
        # a measurement is judged only on having run and measured (a finite error), not on the tolerance
        within = case.kind == "measurement" or res.error <= case.tolerance
        res.passed = bool(math.isfinite(res.error) and within)
        if case.kind == "measurement":
            res.message += " (a measurement: not judged against the tolerance)"
    return res


def refinement_ratio(case: Case) -> float:
    for f in case.refine.values():
        if f > 0 and f != 1:
            return f if f > 1 else 1.0 / f
    return 2.0


def run_refinement(
    case: Case, levels: int, out_root: Path, backend: str | None = None, reuse: bool = False
) -> list[Result]:
    judged = case.refine_tolerance_level if case.refine_tolerance_level is not None else levels - 1
    results = []
    for k in range(levels):
        r = run_case(case, k, out_root, backend, judge=(k == judged), reuse=reuse)
        results.append(r)
    ratio = refinement_ratio(case)
    for a, b in zip(results, results[1:]):
        if a.error and b.error and a.error > 0 and b.error > 0:
            b.order = math.log(a.error / b.error) / math.log(ratio)
    return results
