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


def _extent(bg, rb, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """A body's extent about its centre of mass in its body frame (lowest, highest corner): a Mesh body's
    from its surface in sim.h5, a primitive's from its morph (centred)."""
    if "surface_points" in bg:
        sp = np.asarray(bg["surface_points"][...], dtype=np.float64)[:, :dim]
        return sp.min(axis=0), sp.max(axis=0)
    lo, hi = (np.asarray(b, float)[:dim] for b in rb.morph.bounds())
    return -0.5 * (hi - lo), 0.5 * (hi - lo)


@measurement("rigid_penetration")
def rigid_penetration(f, entity, body, surface, axis=None, **_):
    """Depth [m] of a body's lowest point below the height ``surface`` [m] along ``axis`` (default the
    vertical, the last): an impactor's penetration into a bed whose free surface was at ``surface`` (its
    rotation taken as the initial one: a sphere's lowest point is its centre less its radius whatever it
    does)."""
    scene, rb = _rb_scene(f, body)
    dim = scene.sim.dim
    ax = dim - 1 if axis is None else axis
    bg = _body(f, body)
    rlo, _ = _extent(bg, rb, dim)
    pos = np.asarray(bg["position"][...], dtype=np.float64)
    n = min(len(pos), len(f["time"]))
    return f["time"][:n], float(surface) - (pos[:n, ax] + rlo[ax])


def _rest_volume(scene, entity, n0: int, spacing: float, dim: int) -> float:
    """Rest volume of one particle of ``entity`` [m^dim]: its Box morph's volume over its initial particle
    count (every family fills a Box with particles of equal volume), else spacing^dim."""
    ent = next((e for e in scene.entities if e.name == entity), None)
    if ent is not None and getattr(ent.morph, "type", None) == "Box" and n0 > 0:
        lo, hi = (np.asarray(b, float)[:dim] for b in ent.morph.bounds())
        return float(np.prod(hi - lo)) / n0
    return float(spacing) ** dim


def _mass_level(x, far, ax, y_ref, spacing, vol, area):
    """Depth [m] of liquid above height ``y_ref`` by its mass: the rest volume of the particles ``far``
    above y_ref (a particle within half a spacing of it counted in proportion) over the horizontal
    ``area`` they cover."""
    w = np.clip((x[far, ax] - y_ref) / spacing + 0.5, 0.0, 1.0)
    return float(w.sum()) * vol / area


@measurement("rigid_draft")
def rigid_draft(f, entity, body, axis=None, spacing=0.0, margin=0.02, level="top", **_):
    """Draft [m] of a floating rigid body: the liquid's free surface away from the body (the mean over
    columns of width ``spacing`` of the highest particle, plus half a spacing, for columns farther than
    ``margin`` [m] from the body's extent) minus the lowest point of the body (its centre of mass less its
    half extent along the vertical ``axis``, default the last; a Mesh body: its lowest vertex; for an
    upright body). ``spacing: sph``: the
    scene's SPH particle size (so that a case refined with ``--refine`` measures at its own spacing).

    ``level: mass``: the depth of liquid above the body's lowest point measured by its mass instead of its
    top particles: the rest volume (mass / rho0) of the liquid farther than ``margin`` from the body and
    above that height, over the area it covers (the domain's horizontal extent less the body's, grown by
    the margin). The liquid's pressure there is g times that mass per area (hydrostatics), so this is
    Archimedes' balance itself: the body's weight against the weight of the liquid it displaces. The
    particles' top is not (docs/RIGID.md): a particle liquid's surface layer and bulk pack differently
    from a lattice (in SPH the deficient surface layer sinks 0.15 spacing into the next, DFSPH's bulk
    spreads), so top + half a spacing is off by 0.1-0.3 spacing; PBF's bulk is compressed."""
    scene, rb = _rb_scene(f, body)
    dim = scene.sim.dim
    if spacing == "sph":
        spacing = float(scene.solvers.sph.particle_size)
    ax = dim - 1 if axis is None else axis
    bg = _body(f, body)
    rlo, rhi = _extent(bg, rb, dim)
    pos = np.asarray(bg["position"][...], dtype=np.float64)
    _, g = entity_group(f, entity)
    X = g["position"]
    n = min(len(pos), len(f["time"]), X.shape[0])
    lat = [a for a in range(dim) if a != ax]
    ps = float(spacing) if spacing else 0.01
    if level not in ("top", "mass"):
        raise ValueError(f"rigid_draft: level must be top or mass, not {level!r}")
    if level == "mass":
        vol = _rest_volume(scene, entity, X.shape[1], ps, dim)
        dlo, dhi = (np.asarray(b, float)[:dim] for b in scene.domain.bounds(dim))
    out = np.empty(n)
    for i in range(n):
        x = np.asarray(X[i], dtype=np.float64)
        far = np.zeros(len(x), bool)
        for a in lat:
            far |= (x[:, a] < pos[i, a] + rlo[a] - margin) | (x[:, a] > pos[i, a] + rhi[a] + margin)
        if level == "mass":
            inner = 1.0
            for a in lat:
                inner *= max(
                    0.0, min(dhi[a], pos[i, a] + rhi[a] + margin) - max(dlo[a], pos[i, a] + rlo[a] - margin)
                )
            area = float(np.prod((dhi - dlo)[lat])) - inner
            out[i] = _mass_level(x, far, ax, pos[i, ax] + rlo[ax], ps, vol, area)
            continue
        xs = x[far]
        if len(xs) == 0:
            out[i] = np.nan
            continue
        keys = np.floor(xs[:, lat] / ps).astype(np.int64)
        _, inv = np.unique(keys, axis=0, return_inverse=True)
        tops = np.full(inv.max() + 1, -np.inf)
        np.maximum.at(tops, inv.ravel(), xs[:, ax])
        surface = float(np.mean(tops)) + 0.5 * float(spacing)
        out[i] = surface - (pos[i, ax] + rlo[ax])
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


@measurement("rigid_energy_growth")
def rigid_energy_growth(f, entity="*", **_):
    """(E(t) - E(0)) / E(0) of the total energy without gravity: the entities' kinetic energy (sum m v^2 / 2:
    needs the ``mass`` output field) plus their elastic energy where the ``elastic_energy`` field is written,
    plus every rigid body's translational and rotational kinetic energy (m v^2 / 2 + w.I w / 2, the inertia
    from its shape and rho as the run computed it), clipped below at 0 [-] (as probe_growth): 0 while the
    total never exceeds its start."""
    from simcli.rigid.body import RigidBodyModel
    from simcli.verify.registry import scene_of

    t = np.asarray(f["time"][...], dtype=np.float64)
    n = len(t)
    E = np.zeros(n)
    for name in f["entities"]:
        g = f["entities"][name]
        if "mass" not in g:
            raise KeyError(f"entity '{name}' has no mass field: add mass to output.fields")
        for i in range(n):
            v = np.asarray(g["velocity"][i], float)
            E[i] += 0.5 * float(np.asarray(g["mass"][i], float) @ (v * v).sum(axis=1))
            if "elastic_energy" in g:
                E[i] += float(np.asarray(g["elastic_energy"][i], float).sum())
    if "rigid_bodies" in f:
        scene = scene_of(f)
        dim = int(scene.sim.dim)
        for rb in scene.rigid_bodies:
            g = f["rigid_bodies"][rb.name]
            body = RigidBodyModel(rb, dim, scene)
            v = np.asarray(g["velocity"][:n], float)
            w = np.asarray(g["angular_velocity"][:n], float)
            E += 0.5 * body.mass * (v * v).sum(axis=1)
            if dim == 2:
                E += 0.5 * body.inertia[2, 2] * w[:, 0] ** 2
            else:  # the body-frame inertia turned with the body's orientation
                from simcli.motion import quat_to_matrix

                q = np.asarray(g["orientation"][:n], float)
                for i in range(n):
                    R = quat_to_matrix(q[i])
                    E[i] += 0.5 * float(w[i] @ (R @ body.inertia @ R.T) @ w[i])
    return t, np.maximum(0.0, (E - E[0]) / (E[0] if E[0] > 0 else 1.0))
