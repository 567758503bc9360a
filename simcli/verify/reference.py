"""References (analytic formulas, published tables, single values) and error metrics."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

# reference_dir lives in cases.py with table_path (load_case checks that a case's table exists)
from simcli.verify.cases import (
    Case,
    ErrorSpec,
    Reference,
    reference_dir,  # noqa: F401 - re-exported
    table_path,
)

_SAFE = {
    "np": np,
    "math": math,
    "pi": math.pi,
    "sqrt": np.sqrt,
    "exp": np.exp,
    "sin": np.sin,
    "cos": np.cos,
    "log": np.log,
    "abs": np.abs,
}


def _eval(expr: str, env: dict):
    return eval(expr, {"__builtins__": {}}, {**_SAFE, **env})


def read_table(path: Path) -> np.ndarray:
    rows = []
    for line in path.read_text().splitlines():
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        try:
            rows.append([float(x) for x in s.split(",")])
        except ValueError:
            continue  # a header line
    return np.asarray(rows, dtype=np.float64)


def reference_series(case: Case, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference values at the measured times (analytic, value), or the table's own times
    with the measurement interpolated onto them (returned as (t_ref, ref))."""
    ref: Reference = case.reference
    if ref.value is not None:
        return t, np.full_like(t, ref.value)
    if ref.analytic is not None:
        v = _eval(ref.analytic, {"t": t, **ref.constants})
        return t, np.broadcast_to(np.asarray(v, dtype=np.float64), t.shape).copy()
    tab = read_table(table_path(case))
    tt, vv = tab[:, 0], tab[:, ref.column]
    if ref.scale_t:
        tt = np.asarray(_eval(ref.scale_t, {"x": tt, **ref.constants}), dtype=np.float64)
    if ref.scale_v:
        vv = np.asarray(_eval(ref.scale_v, {"x": vv, **ref.constants}), dtype=np.float64)
    return tt, vv


def period_mean(t: np.ndarray, v: np.ndarray) -> float:
    """Time average of an oscillation over its largest whole number of periods in [t0, t1]."""
    sign = np.sign(v - v.mean())
    cross = t[1:][sign[1:] != sign[:-1]]
    if len(cross) >= 3:
        period = 2.0 * float(np.median(np.diff(cross)))
        k = int((t[-1] - t[0]) // period)
        if k >= 1:
            w = t <= t[0] + k * period
            return float(np.trapezoid(v[w], t[w]) / (t[w][-1] - t[0]))
    half = t >= t[0] + 0.5 * (t[-1] - t[0])
    return float(v[half].mean())


def arrival_time(t: np.ndarray, v: np.ndarray, threshold: float, t0: float = -np.inf) -> float:
    """The first time at or after ``t0`` that ``v`` reaches ``threshold``, interpolated linearly between the
    samples on either side of the crossing; NaN (never reached). NaN samples (a dry probe) count as below."""
    sel = t >= t0
    t, v = t[sel], v[sel]
    above = np.nan_to_num(v, nan=-np.inf) >= threshold
    if not above.any():
        return math.nan
    k = int(np.argmax(above))
    if k == 0 or not np.isfinite(v[k - 1]):
        return float(t[k])
    return float(t[k - 1] + (threshold - v[k - 1]) / (v[k] - v[k - 1]) * (t[k] - t[k - 1]))


def _arrival_error(spec: ErrorSpec, t, measured, t_ref, ref) -> dict:
    t0 = spec.window[0] if spec.window is not None else -np.inf
    if spec.window is not None:
        measured = np.where(t <= spec.window[1] + 1e-12, measured, np.nan)
        ref = np.where(t_ref <= spec.window[1] + 1e-12, ref, np.nan)
    tm = arrival_time(t, measured, spec.threshold, t0)
    tr = arrival_time(t_ref, ref, spec.threshold, t0)
    if not math.isfinite(tr) or tr <= 0:
        raise ValueError(f"the reference never reaches the threshold {spec.threshold:g} in the window")
    err = abs(tm - tr) / tr if math.isfinite(tm) else math.inf
    return {
        "error": float(err),
        "measured": tm,
        "reference": tr,
        "measured_mean": tm,
        "reference_mean": tr,
        "points": len(t),
    }


def window_integral(t: np.ndarray, v: np.ndarray, t0: float, t1: float) -> float:
    """The trapezoidal integral of ``v`` over [t0, t1] on its own samples, the ends interpolated (held
    beyond the series); NaN samples count as 0."""
    t = np.asarray(t, dtype=np.float64)
    v = np.nan_to_num(np.asarray(v, dtype=np.float64), nan=0.0)
    inner = (t > t0) & (t < t1)
    tt = np.concatenate([[t0], t[inner], [t1]])
    return float(np.trapezoid(np.interp(tt, t, v), tt))


def _impulse_error(spec: ErrorSpec, t, measured, t_ref, ref) -> dict:
    t0, t1 = spec.window
    if t_ref.max() < t1 or t.max() < t1 - 1e-9:
        raise ValueError(f"impulse_rel: a series ends before the window's end {t1:g} s")
    im, ir = window_integral(t, measured, t0, t1), window_integral(t_ref, ref, t0, t1)
    if ir == 0:
        raise ValueError("impulse_rel: the reference's impulse over the window is 0")
    return {
        "error": abs(im - ir) / abs(spec.scale or ir),
        "measured": im,
        "reference": ir,
        "measured_mean": im / (t1 - t0),
        "reference_mean": ir / (t1 - t0),
        "points": int(np.sum((t >= t0) & (t <= t1))),
    }


def compute_error(case: Case, t: np.ndarray, measured: np.ndarray) -> dict:
    spec: ErrorSpec = case.error
    t_ref, ref = reference_series(case, t)
    if spec.metric == "arrival_rel":  # each series' own samples: no interpolation across the jump
        return _arrival_error(spec, t, measured, t_ref, ref)
    if spec.metric == "impulse_rel":  # each series' own samples as well
        return _impulse_error(spec, t, measured, t_ref, ref)
    if t_ref is not t:  # a table: interpolate the measurement at the table's times
        lo, hi = t.min(), t.max()
        ok = (t_ref >= lo) & (t_ref <= hi)
        t_ref, ref = t_ref[ok], ref[ok]
        meas = np.interp(t_ref, t, measured)
        tt = t_ref
    else:
        meas, tt = measured, t
    if spec.window is not None:
        sel = (tt >= spec.window[0] - 1e-12) & (tt <= spec.window[1] + 1e-12)
        tt, meas, ref = tt[sel], meas[sel], ref[sel]
    if len(tt) == 0:
        raise ValueError(f"case {case.name}: no measured point inside the comparison window")
    diff = meas - ref
    scale = spec.scale if spec.scale is not None else None
    m = spec.metric
    # the measured value the error is computed from, and the reference it is compared with (report)
    judged, judged_ref = float(meas.mean()), float(ref.mean())
    if m == "max_abs":
        k = int(np.argmax(np.abs(diff)))
        err, judged, judged_ref = np.abs(diff)[k], float(meas[k]), float(ref[k])
    elif m == "max_rel":
        rel = np.abs(diff) / (scale or np.maximum(np.abs(ref), 1e-300))
        k = int(np.argmax(rel))
        err, judged, judged_ref = rel[k], float(meas[k]), float(ref[k])
    elif m == "rms":
        err = math.sqrt(float(np.mean(diff**2)))
    elif m == "rms_rel":
        err = math.sqrt(float(np.mean(diff**2))) / (scale or float(np.sqrt(np.mean(ref**2))))
    elif m == "final_abs":
        err, judged, judged_ref = abs(diff[-1]), float(meas[-1]), float(ref[-1])
    elif m == "final_rel":
        err, judged, judged_ref = abs(diff[-1]) / (scale or abs(ref[-1])), float(meas[-1]), float(ref[-1])
    elif m == "mean_abs":
        err = np.abs(diff).mean()
    elif m == "mean_rel":
        err = (np.abs(diff) / (scale or np.maximum(np.abs(ref), 1e-300))).mean()
    elif m == "period_mean_rel":
        # the static state an undamped oscillation swings about: its time average over the largest
        # whole number of periods in the window (period from the crossings of its mean); a
        # settled, non-oscillating series: the mean of the window's second half
        judged = float(period_mean(tt, meas))
        err = abs(judged - ref.mean()) / (scale or abs(ref.mean()))
    elif m == "midrange_rel":
        # (max + min) / 2 of an oscillation about a static state: the static value, whatever
        # the period, once the window holds a full period
        judged = float(0.5 * (meas.max() + meas.min()))
        err = abs(judged - ref.mean()) / (scale or abs(ref.mean()))
    elif m == "nmae":
        # normalised mean absolute error: mean |measured - reference| over the window / max |reference|
        err = float(np.abs(diff).mean()) / (scale or float(np.abs(ref).max()))
    elif m == "mean_value_abs":
        err = abs(meas.mean() - ref.mean())
    elif m == "mean_value_rel":
        err = abs(meas.mean() - ref.mean()) / (scale or abs(ref.mean()))
    else:  # pragma: no cover - the model restricts metric
        raise ValueError(m)
    return {
        "error": float(err),
        "measured": judged,
        "reference": judged_ref,
        "measured_mean": float(meas.mean()),
        "reference_mean": float(ref.mean()),
        "points": len(tt),
    }
