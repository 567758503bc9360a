"""What `--resume` checks before it continues a run from a checkpoint.

A checkpoint holds the solver state at a step, and the resolved scene it was written with (meta key
``scene``). Resuming with a scene that changes the physics (materials, gravity, solver options,
precision, domain, colliders, entities) or the time axis (``sim.dt``, ``sim.substeps``,
``output.every``) would continue another simulation from this one's state and mix both in one sim.h5:
refused, naming the keys. What may change: how long the run goes on (``sim.steps``, ``sim.duration``),
where and how it runs (``sim.threads``, ``sim.backend``), which formats are written, the checkpoint
policy and the scene's name.

The metadata is checked too (a step, frame and time that agree with each other and with the scene), so
an edited or damaged checkpoint is refused instead of writing wrong frames. Taichi-free."""

from __future__ import annotations

import math

# keys (dotted prefixes) a resumed run may change
RESUME_FREE = (
    "version",
    "name",
    "sim.steps",
    "sim.duration",
    "sim.threads",
    "sim.backend",
    "output.dir",
    "output.formats",
    "checkpoint",
)


def _flatten(d, prefix: str = "") -> dict:
    out = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        if not d and prefix:
            out[prefix] = {}
    elif isinstance(d, list) and any(isinstance(x, (dict, list)) for x in d):
        for i, v in enumerate(d):
            out.update(_flatten(v, f"{prefix}.{i}"))
        out[f"{prefix}.#"] = len(d)  # the number of items (entities, colliders) is itself a key
    else:
        out[prefix] = list(d) if isinstance(d, tuple) else d
    return out


def _families(scene: dict) -> set[str]:
    fams = set()
    for e in scene.get("entities") or []:
        t = str(((e or {}).get("material") or {}).get("type", ""))
        if "." in t:
            fams.add(t.split(".", 1)[0].lower())
    return fams


def _free(key: str) -> bool:
    return any(key == p or key.startswith(p + ".") for p in RESUME_FREE)


def _same(a, b) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        try:
            return float(a) == float(b) or (math.isnan(float(a)) and math.isnan(float(b)))
        except (TypeError, ValueError):
            return False
    return a == b


def scene_differences(saved: dict, current: dict) -> list[str]:
    """``key: value there -> value now`` for every key that differs and matters for a resume."""
    a, b = _flatten(saved), _flatten(current)
    used = _families(saved) | _families(current)
    diffs = []
    for k in sorted(set(a) | set(b), key=lambda k: (k.split(".")[0], k)):
        if _free(k):
            continue
        parts = k.split(".")
        if parts[0] == "solvers" and len(parts) > 1 and parts[1] not in used:
            continue  # options of a family the scene does not use
        va, vb = a.get(k, "(absent)"), b.get(k, "(absent)")
        if not _same(va, vb):
            diffs.append(f"{k}: {va!r} in the checkpoint, {vb!r} now")
    return diffs


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def meta_problems(meta: dict, dt: float, every: int, n_steps: int) -> list[str]:
    """What is inconsistent in a checkpoint's metadata (empty: nothing found)."""
    out = []
    step, frame, t = meta.get("step"), meta.get("frame"), meta.get("time")
    if not _is_int(step) or step < 0:
        out.append(f"step = {step!r} (needs a whole number >= 0)")
    if not _is_int(frame) or frame < 0:
        out.append(f"frame = {frame!r} (needs a whole number >= 0)")
    if out:
        return out
    if step > n_steps:
        out.append(f"step {step} is beyond the scene's last step {n_steps} (sim.steps / sim.duration)")
    if frame != step // every:
        out.append(
            f"frame {frame} does not match step {step} with output.every = {every} (expected {step // every})"
        )
    if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t):
        out.append(f"time = {t!r} (needs a finite number)")
    elif not math.isclose(t, step * dt, rel_tol=1e-9, abs_tol=1e-12 * max(dt, 1e-300)):
        out.append(f"time {t!r} s is not step * sim.dt = {step} * {dt!r} = {step * dt!r} s")
    sn = meta.get("substeps_now")
    if sn is not None and (not _is_int(sn) or sn < 1):
        out.append(f"substeps_now = {sn!r} (needs a whole number >= 1)")
    hist = meta.get("substeps_hist", [])
    if not isinstance(hist, list) or not all(_is_int(x) and x >= 1 for x in hist):
        out.append("substeps_hist holds something other than whole numbers >= 1")
    dr = meta.get("dt_range")
    if dr is not None and (
        not isinstance(dr, list)
        or len(dr) != 2
        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and x >= 0 for x in dr)
    ):
        out.append(f"dt_range = {dr!r} (needs [smallest, largest] substep, both >= 0)")
    return out
