"""Measurements: quantities extracted from a run's ``sim.h5``, each a time series.

Register a new one with ``@measurement("name")``; a function gets the open HDF5 file, the
entity name and the case's ``params``/``axis`` and returns ``(t, values)``.
"""

from __future__ import annotations

from collections.abc import Callable

import h5py
import numpy as np

MEASUREMENTS: dict[str, Callable] = {}


def measurement(name: str):
    def deco(fn):
        MEASUREMENTS[name] = fn
        return fn

    return deco


def _entity(f: h5py.File, entity: str | None) -> tuple[str, h5py.Group]:
    names = list(f["entities"].keys())
    if entity is None:
        entity = names[0]
    if entity not in names:
        raise KeyError(f"entity '{entity}' not in sim.h5 (has {', '.join(names)})")
    return entity, f["entities"][entity]


def _positions(g: h5py.Group) -> np.ndarray:
    return np.asarray(g["position"][...], dtype=np.float64)


@measurement("com")
def com(f, entity, axis=2, **_):
    """Centre of mass along ``axis`` (particles of one entity carry equal mass)."""
    _, g = _entity(f, entity)
    return f["time"][...], _positions(g)[:, :, axis].mean(axis=1)


@measurement("com_drift")
def com_drift(f, entity, axis=None, axes=(0, 1), **_):
    """Largest displacement of the centre of mass along the given (lateral) axes."""
    _, g = _entity(f, entity)
    x = _positions(g)
    c = x[:, :, list(axes)].mean(axis=1)
    return f["time"][...], np.abs(c - c[0]).max(axis=1)


@measurement("min_coord")
def min_coord(f, entity, axis=2, **_):
    """Lowest particle coordinate along ``axis`` (penetration of a floor)."""
    _, g = _entity(f, entity)
    return f["time"][...], _positions(g)[:, :, axis].min(axis=1)


@measurement("depth_below")
def depth_below(f, entity, axis=2, level=0.0, **_):
    """How far the lowest particle is below ``level`` along ``axis`` (0 when none is)."""
    _, g = _entity(f, entity)
    return f["time"][...], np.maximum(0.0, level - _positions(g)[:, :, axis].min(axis=1))


@measurement("gap_change")
def gap_change(f, entity, axis=2, band=None, **_):
    """Change of the distance between the top and bottom particle layers along ``axis``
    (compression of a column), layers taken from the initial positions within ``band`` [m]
    of the extremes (default: a quarter of the typical spacing)."""
    _, g = _entity(f, entity)
    x = _positions(g)
    z0 = x[0, :, axis]
    if band is None:
        band = 0.25 * (z0.max() - z0.min()) / max(1.0, round(len(np.unique(np.round(z0, 9))) - 1))
    top = z0 >= z0.max() - band
    bot = z0 <= z0.min() + band
    gap = x[:, top, axis].mean(axis=1) - x[:, bot, axis].mean(axis=1)
    return f["time"][...], gap - gap[0]


@measurement("region_displacement")
def region_displacement(f, entity, axis=2, lower=None, upper=None, **_):
    """Mean displacement along ``axis`` of the particles initially inside the box
    [lower, upper] (a beam tip)."""
    _, g = _entity(f, entity)
    x = _positions(g)
    x0 = x[0]
    sel = np.all((x0 >= np.asarray(lower)) & (x0 <= np.asarray(upper)), axis=1)
    if not sel.any():
        raise ValueError("region_displacement: no particle inside the region")
    return f["time"][...], (x[:, sel, axis] - x0[sel, axis]).mean(axis=1)


@measurement("percentile")
def percentile(f, entity, axis=0, q=99.0, offset=0.0, **_):
    """The q-th percentile of the coordinate along ``axis`` minus ``offset`` (a surge front)."""
    _, g = _entity(f, entity)
    return f["time"][...], np.percentile(_positions(g)[:, :, axis], q, axis=1) - offset


@measurement("max_speed")
def max_speed(f, entity, **_):
    _, g = _entity(f, entity)
    v = np.asarray(g["velocity"][...], dtype=np.float64)
    return f["time"][...], np.linalg.norm(v, axis=2).max(axis=1)


@measurement("kinetic_energy")
def kinetic_energy(f, entity, mass=1.0, **_):
    """Kinetic energy per unit particle mass times ``mass`` (total mass of the body) [J]."""
    _, g = _entity(f, entity)
    v = np.asarray(g["velocity"][...], dtype=np.float64)
    return f["time"][...], 0.5 * mass * (v * v).sum(axis=2).mean(axis=1)


def run_measurement(h5_path, quantity: str, entity: str | None, axis: int | None, params: dict):
    if quantity not in MEASUREMENTS:
        raise KeyError(f"unknown measurement '{quantity}' (known: {', '.join(sorted(MEASUREMENTS))})")
    kw = dict(params)
    if axis is not None:
        kw["axis"] = axis
    with h5py.File(h5_path, "r", swmr=True) as f:
        t, v = MEASUREMENTS[quantity](f, entity, **kw)
    return np.asarray(t, dtype=np.float64), np.asarray(v, dtype=np.float64)
