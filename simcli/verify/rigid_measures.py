"""Validation measurements of rigid bodies (sim.h5 /rigid_bodies/<name>/...; registered in
simcli.verify.registry's MEASUREMENTS): each takes the open sim.h5, the entity name and the case's params
and returns (t, values)."""

from __future__ import annotations

import numpy as np

from simcli.verify.registry import entity_group, measurement


def _body(f, body):
    if "rigid_bodies" not in f or body not in f["rigid_bodies"]:
        have = ", ".join(f["rigid_bodies"].keys()) if "rigid_bodies" in f else "none"
        raise KeyError(f"rigid body '{body}' not in sim.h5 (rigid bodies: {have})")
    return f["rigid_bodies"][body]


def _rb_scene(f, body):
    import yaml

    from simcli.scene.models import Scene

    scene = Scene.model_validate(yaml.safe_load(f.attrs["scene"]))
    rb = next(r for r in scene.rigid_bodies if r.name == body)
    return scene, rb


@measurement("rigid")
def rigid(f, entity, body, field="position", axis=None, **_):
    """A rigid body's output ``field`` (position, orientation, velocity, angular_velocity, force, torque):
    one ``axis`` or the magnitude."""
    d = np.asarray(_body(f, body)[field][...], dtype=np.float64)
    n = min(len(d), len(f["time"]))
    v = np.linalg.norm(d[:n], axis=1) if axis is None else d[:n, axis]
    return f["time"][:n], v


@measurement("rigid_draft")
def rigid_draft(f, entity, body, axis=None, spacing=0.0, margin=0.02, **_):
    """Draft [m] of a floating rigid body: the liquid's free surface away from the body (the mean over
    columns of width ``spacing`` of the highest particle, plus half a spacing, for columns farther than
    ``margin`` [m] from the body's extent) minus the lowest point of the body (its centre of mass less its
    half extent along the vertical ``axis``, default the last; for an upright body). ``spacing: sph``: the
    scene's SPH particle size (so that a case refined with ``--refine`` measures at its own spacing)."""
    scene, rb = _rb_scene(f, body)
    dim = scene.sim.dim
    if spacing == "sph":
        spacing = float(scene.solvers.sph.particle_size)
    ax = dim - 1 if axis is None else axis
    lo, hi = (np.asarray(b, float)[:dim] for b in rb.morph.bounds())
    half = 0.5 * (hi - lo)
    pos = np.asarray(_body(f, body)["position"][...], dtype=np.float64)
    _, g = entity_group(f, entity)
    X = g["position"]
    n = min(len(pos), len(f["time"]), X.shape[0])
    lat = [a for a in range(dim) if a != ax]
    ps = float(spacing) if spacing else 0.01
    out = np.empty(n)
    for i in range(n):
        x = np.asarray(X[i], dtype=np.float64)
        far = np.zeros(len(x), bool)
        for a in lat:
            far |= np.abs(x[:, a] - pos[i, a]) > half[a] + margin
        xs = x[far]
        if len(xs) == 0:
            out[i] = np.nan
            continue
        keys = np.floor(xs[:, lat] / ps).astype(np.int64)
        _, inv = np.unique(keys, axis=0, return_inverse=True)
        tops = np.full(inv.max() + 1, -np.inf)
        np.maximum.at(tops, inv.ravel(), xs[:, ax])
        surface = float(np.mean(tops)) + 0.5 * float(spacing)
        out[i] = surface - (pos[i, ax] - half[ax])
    return f["time"][:n], out


@measurement("rigid_momentum_error")
def rigid_momentum_error(f, entity="*", axis=None, **_):
    """|P(t) - P(0)| / |P(0)| of the total linear momentum of every entity (sum m v: needs the ``mass``
    output field) and every rigid body (mass from sim.h5 attrs) [-]."""
    t = np.asarray(f["time"][...], dtype=np.float64)
    n = len(t)
    P = np.zeros((n, int(f.attrs.get("dim", 3))))
    for name in f["entities"]:
        g = f["entities"][name]
        if "mass" not in g:
            raise KeyError(f"entity '{name}' has no mass field: add mass to output.fields")
        for i in range(n):
            P[i] += np.asarray(g["mass"][i], float) @ np.asarray(g["velocity"][i], float)
    for name in f.get("rigid_bodies", {}):
        g = f["rigid_bodies"][name]
        P += float(g.attrs["mass"]) * np.asarray(g["velocity"][:n], float)
    if axis is not None:
        P = P[:, axis : axis + 1]
    ref = np.linalg.norm(P[0])
    return t, np.linalg.norm(P - P[0], axis=1) / (ref if ref > 0 else 1.0)
