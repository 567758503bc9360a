"""Validation measurements of PBD runs (registered in simcli.verify.registry's MEASUREMENTS): each takes the
open sim.h5, the entity name and the case's params and returns (t, values)."""

from __future__ import annotations

import numpy as np

from simcli.verify.registry import entity_group, measurement


@measurement("pbd_period")
def pbd_period(f, entity, vertex=1, anchor=0, **_):
    """Mean oscillation period [s] of the distance between two vertices (``vertex`` and ``anchor``):
    the mean spacing of its upward crossings of its mid-range, times from linear interpolation
    (output every step). One value, at the last frame's time."""
    _, g = entity_group(f, entity)
    x = np.asarray(g["position"][...], dtype=np.float64)
    t = np.asarray(f["time"][...], dtype=np.float64)
    d = np.linalg.norm(x[:, vertex] - x[:, anchor], axis=1)
    y = d - 0.5 * (d.max() + d.min())
    up = np.nonzero((y[:-1] < 0) & (y[1:] >= 0))[0]
    if len(up) < 2:
        raise ValueError("pbd_period: fewer than two oscillations in the run")
    tc = t[up] + (t[up + 1] - t[up]) * (-y[up]) / (y[up + 1] - y[up])
    return t[-1:], np.array([float(np.mean(np.diff(tc)))])


@measurement("pbd_sag")
def pbd_sag(f, entity, axis=2, **_):
    """Sag [m]: height of the highest vertex at the start (the supports) minus the lowest vertex now."""
    _, g = entity_group(f, entity)
    x = np.asarray(g["position"][...], dtype=np.float64)
    return f["time"][...], x[0, :, axis].max() - x[:, :, axis].min(axis=1)


@measurement("pbd_support_force")
def pbd_support_force(f, entity, axis=2, **_):
    """Total force [N] the supports exert on the body along ``axis`` (sum of the `reaction` field, which is
    non-zero on pinned vertices only)."""
    _, g = entity_group(f, entity)
    if "reaction" not in g:
        raise KeyError(
            "pbd_support_force needs the 'reaction' output field (output.fields: [position, "
            "velocity, reaction])"
        )
    r = np.asarray(g["reaction"][...], dtype=np.float64)
    return f["time"][...], r[:, :, axis].sum(axis=1)


@measurement("pbd_sphere_penetration")
def pbd_sphere_penetration(f, entity, center, radius, **_):
    """How far the deepest vertex is inside a sphere of ``center`` and ``radius`` [m] (0 when none is)."""
    _, g = entity_group(f, entity)
    x = np.asarray(g["position"][...], dtype=np.float64)
    d = np.linalg.norm(x - np.asarray(center, dtype=np.float64), axis=2).min(axis=1)
    return f["time"][...], np.maximum(0.0, float(radius) - d)
