"""Validation measurements of FEM runs (registered in simcli.verify.registry's MEASUREMENTS): each takes the
open sim.h5, the entity name and the case's params and returns (t, values)."""

from __future__ import annotations

import math

import numpy as np

from simcli.verify.registry import entity_group, measurement


def slowest_mode(g, time, lower, upper, axis, skip, modes, name: str):
    """(times, dt, lambda) of the slowest vibration mode in the mean displacement along ``axis`` of an
    entity's vertices initially inside [lower, upper] (output every step, constant dt): the series after
    ``skip`` frames fitted by linear prediction with ``modes`` modes and a constant (y_n+1 = sum_k a_k
    y_n-k + c, exact for a sum of modes of a linear one-step method); lambda is the root of smallest
    positive phase, the mode's amplification per step. ``name`` heads the error messages."""
    x = np.asarray(g["position"][...], dtype=np.float64)
    if "displacement" in g:  # (FEM) exact to f32 round-off of the small displacement, not of the position
        x0 = x[0] - np.asarray(g["displacement"][0], dtype=np.float64)
        u = np.asarray(g["displacement"][...], dtype=np.float64)
    else:
        x0, u = x[0], x - x[0]
    sel = np.all((x0 >= np.asarray(lower)) & (x0 <= np.asarray(upper)), axis=1)
    if not sel.any():
        raise ValueError(f"{name}: no vertex inside the region")
    t = np.asarray(time, dtype=np.float64)
    dt = float(t[1] - t[0])
    y = u[int(skip) :, sel, axis].mean(axis=1)
    p = 2 * int(modes)
    if len(y) < 4 * p:
        raise ValueError(f"{name}: {len(y)} frames after skip, need at least {4 * p}")
    A = np.stack([y[p - 1 - k : len(y) - 1 - k] for k in range(p)] + [np.ones(len(y) - p)], axis=1)
    coef, *_ = np.linalg.lstsq(A, y[p:], rcond=None)
    roots = np.roots(np.concatenate([[1.0], -coef[:p]]))
    osc = roots[np.imag(roots) > 1e-12]
    if len(osc) == 0:
        raise ValueError(f"{name}: no oscillating mode found in the series")
    return t, dt, osc[np.argmin(np.angle(osc))]


@measurement("mode_frequency")
def mode_frequency(
    f, entity, axis=2, lower=None, upper=None, skip=0, modes=3, scheme="implicit_midpoint", **_
):
    """Frequency [Hz] of the slowest vibration mode in the mean displacement along ``axis`` of the vertices
    initially inside [lower, upper] (a beam tip; output every step, constant dt). The series after ``skip``
    frames is fitted by linear prediction with ``modes`` modes and a constant (y_n+1 = sum_k a_k y_n-k + c,
    exact for a sum of modes of a linear one-step method); the root of smallest positive phase theta per step
    is the slowest mode. ``scheme`` removes the integrator's own phase error: the midpoint rule (and
    Newmark's trapezoidal rule) turns an undamped mode of angular frequency w into the phase
    theta = 2 atan(w dt / 2), so w = 2 tan(theta / 2) / dt exactly; ``none`` takes w = theta / dt. The
    measured frequency is then the spatial discretisation's own (the mesh, the element, the mass lumping),
    free of the time step's period error. One value, at the last frame's time."""
    _, g = entity_group(f, entity)
    t, dt, lam = slowest_mode(g, f["time"][...], lower, upper, axis, skip, modes, "mode_frequency")
    theta = float(np.angle(lam))
    if scheme == "implicit_midpoint":
        w = 2.0 * math.tan(0.5 * theta) / dt
    elif scheme == "none":
        w = theta / dt
    else:
        raise ValueError(f"mode_frequency: scheme {scheme!r}: give implicit_midpoint or none")
    return t[-1:], np.array([w / (2.0 * math.pi)])
