"""Validation measurements of emitters and sinks (registered in simcli.verify.registry's MEASUREMENTS): each
takes the open sim.h5, the entity name and the case's params and returns (t, values)."""

from __future__ import annotations

import numpy as np

from simcli.verify.registry import measurement


def _series(f, group: str, name: str, what: str):
    if group not in f or name not in f[group]:
        have = ", ".join(f[group].keys()) if group in f else "none"
        raise KeyError(
            f"{group[:-1]} '{name}' not in sim.h5 ({group}: {have}); give params: {{name: <name>}}"
        )
    d = np.asarray(f[group][name][what][...], dtype=np.float64)
    n = min(len(d), len(f["time"]))
    return f["time"][:n], d[:n]


@measurement("emitted_mass")
def emitted_mass(f, entity=None, name=None, **_):
    """Mass [kg] (per metre of depth in 2D) an emitter has let in since the start (sim.h5
    /emitters/<name>/emitted_mass)."""
    return _series(f, "emitters", name, "emitted_mass")


@measurement("removed_mass")
def removed_mass(f, entity=None, name=None, **_):
    """Mass [kg] (per metre of depth in 2D) a sink has taken out since the start
    (/sinks/<name>/removed_mass)."""
    return _series(f, "sinks", name, "removed_mass")


def _live(f, entity, field="position"):
    g = f["entities"][entity]
    x = np.asarray(g[field][...], dtype=np.float64)
    c = np.asarray(g["count"][...]) if "count" in g else np.full(len(x), x.shape[1])
    return x, c


@measurement("surface_level")
def surface_level(f, entity, axis=1, lo=None, hi=None, q=98.0, spacing=0.0, **_):
    """Free-surface level [m] of an entity's live particles inside the band lo <= x[0] <= hi (the tank, away
    from its outflow): the q-th percentile of their coordinate along ``axis`` plus half a spacing."""
    x, c = _live(f, entity)
    out = np.full(len(x), np.nan)
    for k in range(len(x)):
        p = x[k, : c[k]]
        if lo is not None:
            p = p[(p[:, 0] >= lo) & (p[:, 0] <= hi)]
        if len(p):
            out[k] = np.percentile(p[:, axis], q) + 0.5 * spacing
    n = min(len(out), len(f["time"]))
    return f["time"][:n], out[:n]


@measurement("jet_speed")
def jet_speed(f, entity, axis=1, level=0.0, band=0.01, lo=None, hi=None, **_):
    """Mean speed [m/s] along -axis of the live particles within ``band`` of ``level`` (a plane below an
    orifice) and lo <= x[0] <= hi; NaN at frames with none there."""
    x, c = _live(f, entity)
    v, _ = _live(f, entity, "velocity")
    out = np.full(len(x), np.nan)
    for k in range(len(x)):
        p, u = x[k, : c[k]], v[k, : c[k]]
        sel = np.abs(p[:, axis] - level) <= band
        if lo is not None:
            sel &= (p[:, 0] >= lo) & (p[:, 0] <= hi)
        if sel.any():
            out[k] = -float(u[sel, axis].mean())
    n = min(len(out), len(f["time"]))
    return f["time"][:n], out[:n]


@measurement("mass_balance")
def mass_balance(f, entity=None, name=None, sink=None, probe=None, **_):
    """emitted - removed - (alive - alive at the start) [kg] (per metre of depth in 2D) at each frame: an
    emitter's /emitters/<name>/emitted_mass, a sink's /sinks/<sink>/removed_mass and a total-mass probe
    (/probes/<probe>/value, entity "*", interpolated to the frame times): zero to round-off when nothing
    is lost or created (a reusing emitter's slots included)."""
    t, emitted = _series(f, "emitters", name, "emitted_mass")
    _t, removed = _series(f, "sinks", sink, "removed_mass")
    if "probes" not in f or probe not in f["probes"]:
        raise KeyError(f"probe '{probe}' not in sim.h5; give params: {{probe: <a total mass probe>}}")
    pt = np.asarray(f["probes"][probe]["time"][...], dtype=np.float64)
    pm = np.asarray(f["probes"][probe]["value"][...], dtype=np.float64).reshape(len(pt), -1)[:, 0]
    n = min(len(t), len(removed))
    t = np.asarray(t[:n], dtype=np.float64)
    alive = np.interp(t, pt, pm)
    return t, emitted[:n] - removed[:n] - (alive - pm[0])
