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


# ------------------------------------------------------------------ MPM validation measures


def _stack(f, entity, field: str = "position") -> np.ndarray:
    """``field`` of one entity, or of every entity side by side when ``entity`` is ``"*"``:
    (frames, particles, ...) as float64."""
    if entity == "*":
        groups = list(f["entities"].values())
        return np.concatenate([np.asarray(g[field][...], dtype=np.float64) for g in groups], axis=1)
    _, g = _entity(f, entity)
    return np.asarray(g[field][...], dtype=np.float64)


@measurement("pressure_at_depth")
def pressure_at_depth(f, entity, depth, axis=None, band=None, spacing=None, **_):
    """Mean particle pressure [Pa] at ``depth`` [m] below the free surface (a hydrostatic column):
    particles within ``band`` (default ``spacing``) of that depth along the vertical ``axis``
    (default the last). The surface is the median height of the top layer of particles plus half the
    particle ``spacing``."""
    x = _stack(f, entity)
    p = _stack(f, entity, "pressure")
    ax = x.shape[2] - 1 if axis is None else axis
    z = x[:, :, ax]
    if spacing is None:
        levels = np.unique(np.round(z[0], 9))
        spacing = float(np.median(np.diff(levels))) if len(levels) > 1 else 0.0
    band = spacing if band is None else band
    # the top layer's median height (not the highest particle: one displaced particle would move it)
    top = z.max(axis=1, keepdims=True)
    surface = np.array([[np.median(zf[zf >= tf[0] - 0.5 * spacing])] for zf, tf in zip(z, top)]) + 0.5 * spacing
    sel = np.abs((surface - z) - depth) <= 0.5 * band
    counts = sel.sum(axis=1)
    if np.any(counts == 0):
        raise ValueError(f"pressure_at_depth: no particle within {band} m of depth {depth} m in some frame")
    return f["time"][...], (p * sel).sum(axis=1) / counts


@measurement("surge_front")
def surge_front(f, entity, axis=0, q=99.0, wall=0.0, spacing=0.0, time_shift=0.0, **_):
    """Surge front [m] from a ``wall`` along ``axis``: the q-th percentile of the particle coordinate
    plus half a particle ``spacing`` (the liquid's edge), so one splashed particle does not count.
    ``time_shift`` [s] is added to the times (an experiment's gate-opening delay)."""
    x = _stack(f, entity)[:, :, axis]
    return f["time"][...] + time_shift, np.percentile(x, q, axis=1) + 0.5 * spacing - wall


@measurement("runout")
def runout(f, entity, width, axis=0, wall=0.0, q=99.5, spacing=0.0, **_):
    """Normalised run-out (L - L0) / L0 of a collapsing column of initial ``width`` L0 [m] against a
    ``wall``: L is the q-th percentile of the coordinate along ``axis`` plus half a ``spacing``."""
    x = _stack(f, entity)[:, :, axis]
    front = np.percentile(x, q, axis=1) + 0.5 * spacing - wall
    return f["time"][...], (front - width) / width


@measurement("surface_angle")
def surface_angle(f, entity, axis=0, up=None, bin=0.01, lo=0.2, hi=0.8, **_):
    """Slope [deg] of a heap's free surface: the highest particle per ``bin`` [m] along ``axis``,
    fitted by a line over the part of the heap between ``lo`` and ``hi`` of its height; positive
    for a surface that falls along +axis. ``up``: the vertical axis (default the last)."""
    x = _stack(f, entity)
    up = x.shape[2] - 1 if up is None else up
    out = []
    for frame in x:
        a, z = frame[:, axis], frame[:, up]
        k = np.floor((a - a.min()) / bin).astype(np.int64)
        top = np.full(k.max() + 1, -np.inf)
        np.maximum.at(top, k, z)
        centres = a.min() + (np.arange(len(top)) + 0.5) * bin
        base = z.min()
        h = top - base
        sel = np.isfinite(h) & (h >= lo * h.max()) & (h <= hi * h.max())
        if sel.sum() < 3:
            out.append(np.nan)
            continue
        slope = np.polyfit(centres[sel], h[sel], 1)[0]
        out.append(np.degrees(np.arctan(-slope)))
    return f["time"][...], np.asarray(out)


@measurement("min_separation")
def min_separation(f, entity, other, spacing, **_):
    """Smallest distance between a particle of ``entity`` and one of ``other``, in particle
    ``spacing`` units (0 or less would be interpenetration; two bodies in contact through one MPM
    grid stay about a cell apart)."""
    a = _stack(f, entity)
    b = _stack(f, other)
    out = []
    for xa, xb in zip(a, b):
        best = np.inf
        for k in range(0, len(xa), 512):  # blocks: memory stays small
            d2 = ((xa[k:k + 512, None, :] - xb[None, :, :]) ** 2).sum(axis=2)
            best = min(best, float(d2.min()))
        out.append(np.sqrt(best) / spacing)
    return f["time"][...], np.asarray(out)


@measurement("energy")
def energy(f, entity="*", part="total", gravity=None, relative=True, **_):
    """Energy of the entity (``"*"``: all) [J, per metre in 2D]: ``part`` kinetic (sum m v^2 / 2),
    potential (-sum m g.x, ``gravity`` default -9.81 along the last axis), elastic (the
    ``elastic_energy`` output field) or total; ``relative``: divided by the total at t = 0.
    Needs the ``mass`` and (for elastic/total) ``elastic_energy`` output fields."""
    x = _stack(f, entity)
    v = _stack(f, entity, "velocity")
    m = _stack(f, entity, "mass")
    g = np.zeros(x.shape[2])
    g[-1] = -9.81
    if gravity is not None:
        g = np.asarray(gravity, dtype=np.float64)
    kin = 0.5 * (m * (v * v).sum(axis=2)).sum(axis=1)
    pot = -(m * (x @ g)).sum(axis=1)
    parts = {"kinetic": kin, "potential": pot}
    if part in ("elastic", "total"):
        parts["elastic"] = _stack(f, entity, "elastic_energy").sum(axis=1)
    val = parts[part] if part != "total" else kin + pot + parts["elastic"]
    if relative:
        e0 = kin[0] + pot[0] + (parts["elastic"][0] if "elastic" in parts else 0.0)
        val = val / e0
    return f["time"][...], val


@measurement("interpenetration")
def interpenetration(f, entity, other, **_):
    """How far [m] the outermost particle of ``entity`` lies beyond the outermost particle of
    ``other`` along the line joining their centroids (0 while the two particle sets stay apart
    along it; two convex bodies colliding head-on interpenetrate exactly when this is > 0)."""
    a = _stack(f, entity)
    b = _stack(f, other)
    out = []
    for xa, xb in zip(a, b):
        n = xb.mean(axis=0) - xa.mean(axis=0)
        n /= np.linalg.norm(n)
        out.append(max(0.0, float((xa @ n).max() - (xb @ n).min())))
    return f["time"][...], np.asarray(out)
