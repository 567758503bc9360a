"""Validation measurements of coupled runs (two families meeting; docs/COUPLING.md), registered in
simcli.verify.registry's MEASUREMENTS: each takes the open sim.h5, the entity name and the case's params and
returns (t, values)."""

from __future__ import annotations

import numpy as np

from simcli.verify.registry import entity_group, measurement


def _pos(f, name: str) -> np.ndarray:
    _, g = entity_group(f, name)
    return np.asarray(g["position"][...], dtype=np.float64)


def _lattice_spacing(x0: np.ndarray, axis: int) -> float:
    """The spacing of a body's initial particle lattice along ``axis`` [m]."""
    c = np.unique(np.round(x0[:, axis], 9))
    return float(np.median(np.diff(c))) if len(c) > 1 else 0.0


def _is_mesh(f, name: str) -> bool:
    """Whether the entity is written as a mesh (cells: FEM, PBD cloth and soft bodies), not as particles."""
    _, g = entity_group(f, name)
    return "cells" in g


@measurement("draft_fraction")
def draft_fraction(f, entity, liquid, axis=None, spacing=0.0, margin=0.05, level="top", **_):
    """How much of a floating body's height is below the liquid's free surface [-], per frame: (level -
    bottom) / (top - bottom). The body's bottom and top are its lowest and highest particles, extended by half
    its particle spacing (from its initial lattice), or a mesh's (FEM, PBD soft body) lowest and highest
    vertices; the level is the median over the liquid's columns (bins
    of ``spacing`` [m], the liquid's particle size) farther than ``margin`` [m] from the body of the highest
    particle, plus half the liquid's spacing.

    ``level: mass``: the liquid's depth above the body's bottom by its mass instead (rigid_measures.py's
    rigid_draft, docs/RIGID.md): the rest volume of the liquid's particles above the bottom whose columns are
    farther than ``margin`` from the body (in every horizontal direction: a ring), over the area of the
    domain outside the body's box grown by the margin; a particle's rest volume is its entity's Box volume
    over its initial count."""
    from simcli.verify.rigid_measures import _mass_level, _rest_volume

    b = _pos(f, entity)
    w = _pos(f, liquid)
    ax = b.shape[2] - 1 if axis is None else int(axis)
    lat = [a for a in range(b.shape[2]) if a != ax]
    # a particle body's outer particles sit half a spacing inside its surface; a mesh's (FEM, a PBD soft body:
    # an entity with cells) vertices are its surface
    hb = 0.0 if _is_mesh(f, entity) else 0.5 * _lattice_spacing(b[0], ax)
    if level not in ("top", "mass"):
        raise ValueError(f"draft_fraction: level must be top or mass, not {level!r}")
    if level == "mass" and not float(spacing) > 0:
        raise ValueError("draft_fraction: level mass needs the liquid's particle spacing (spacing > 0)")
    if level == "mass":
        import yaml

        from simcli.scene.models import Scene

        scene = Scene.model_validate(yaml.safe_load(f.attrs["scene"]))
        dim = scene.sim.dim
        vol = _rest_volume(scene, liquid, w.shape[1], spacing, dim)
        dlo, dhi = (np.asarray(v, float)[:dim] for v in scene.domain.bounds(dim))
    out = []
    for xb, xw in zip(b, w):
        far = np.zeros(len(xw), bool)
        for a in lat:
            far |= (xw[:, a] < xb[:, a].min() - margin) | (xw[:, a] > xb[:, a].max() + margin)
        bot, top = xb[:, ax].min() - hb, xb[:, ax].max() + hb
        if level == "mass":
            inner = 1.0
            for a in lat:
                lo_a = max(dlo[a], xb[:, a].min() - margin)
                hi_a = min(dhi[a], xb[:, a].max() + margin)
                inner *= max(0.0, hi_a - lo_a)
            area = float(np.prod((dhi - dlo)[lat])) - inner
            out.append(_mass_level(xw, far, ax, bot, spacing, vol, area) / (top - bot))
            continue
        far = np.ones(len(xw), bool)
        for a in lat:
            far &= (xw[:, a] < xb[:, a].min() - margin) | (xw[:, a] > xb[:, a].max() + margin)
        cols = {}
        keys = np.floor(xw[far][:, lat] / spacing).astype(np.int64)
        for k, z in zip(map(tuple, keys), xw[far][:, ax]):
            cols[k] = max(cols.get(k, -np.inf), z)
        lvl = float(np.median(list(cols.values()))) + 0.5 * spacing if cols else np.nan
        out.append((lvl - bot) / (top - bot))
    return f["time"][...], np.asarray(out)


@measurement("probe_growth")
def probe_growth(f, entity=None, names=(), **_):
    """Growth of the sum of scalar probes (e.g. kinetic + elastic energy) over its first sample, relative to
    it, clipped below at 0 [-]: 0 while the sum never exceeds its start."""
    s = None
    t = None
    for name in names:
        g = f["probes"][name]
        n = min(g["time"].shape[0], g["value"].shape[0])
        v = np.asarray(g["value"][:n], dtype=np.float64).reshape(n, -1).sum(axis=1)
        t = g["time"][:n] if t is None else t[:n]
        s = v if s is None else s[:n] + v[: len(s)]
    if s is None:
        raise KeyError("probe_growth: give params: {names: [<probe>, ...]}")
    return t, np.maximum(0.0, (s - s[0]) / abs(s[0]))


@measurement("depth_inside")
def depth_inside(f, entity, other, spacing, **_):
    """Deepest penetration of ``other``'s particles into ``entity`` in units of ``spacing`` [-], per frame:
    for each particle of ``other`` inside the bounding box of ``entity``, its distance to the box's nearest
    face (0 when none is inside). For a convex, roughly box-shaped body (a block), an upper bound of how deep
    the other material went in. A tet mesh (FEM, a PBD soft body) is tested exactly in its deformed shape: the
    particles inside one of its tetrahedra, each one's distance to the mesh's surface triangles."""
    a = _pos(f, entity)
    b = _pos(f, other)
    _, g = entity_group(f, entity)
    if "cells" in g and g["cells"].shape[1] == 4 and a.shape[2] == 3:  # a tet mesh: the exact test
        tets = np.asarray(g["cells"][...], dtype=np.int64)
        return f["time"][...], np.asarray([_depth_in_tets(xa, tets, xb) / spacing for xa, xb in zip(a, b)])
    out = []
    for xa, xb in zip(a, b):
        lo, hi = xa.min(axis=0), xa.max(axis=0)
        inside = np.all((xb > lo) & (xb < hi), axis=1)
        if not inside.any():
            out.append(0.0)
            continue
        d = np.minimum(xb[inside] - lo, hi - xb[inside]).min(axis=1)
        out.append(float(d.max()) / spacing)
    return f["time"][...], np.asarray(out)


def _depth_in_tets(x: np.ndarray, tets: np.ndarray, p: np.ndarray) -> float:
    """How deep the deepest point of ``p`` lies inside the tet mesh (x, tets) [m]: its exact distance to the
    mesh's surface triangles; 0 when none is inside."""
    from simcli.collider_mesh import mesh_distance
    from simcli.geometry.tetmesh import boundary_faces, points_in_tets

    q = p[points_in_tets(x, tets, p)]
    if not len(q):
        return 0.0
    return float(mesh_distance(x, boundary_faces(tets, x), q).max())


@measurement("speed_excess")
def speed_excess(f, entity="*", bound=1.0, **_):
    """How much the largest particle speed of ``entity`` (``"*"``: every entity) exceeds ``bound`` [m/s], per
    frame, clipped below at 0: 0 while nothing moves faster than the bound (an explosion check)."""
    names = list(f["entities"].keys()) if entity == "*" else [entity]
    out = None
    for name in names:
        _, g = entity_group(f, name)
        v = np.asarray(g["velocity"][...], dtype=np.float64)
        s = np.sqrt((v * v).sum(axis=2)).max(axis=1)
        out = s if out is None else np.maximum(out, s)
    return f["time"][...], np.maximum(0.0, out - float(bound))


@measurement("lowest_so_far")
def lowest_so_far(f, entity, axis=None, **_):
    """The lowest coordinate along ``axis`` (default: the last) any particle of ``entity`` has reached up to
    each frame [m] (a running minimum: whether a body ever reached the floor, bouncing or not)."""
    x = _pos(f, entity)
    ax = x.shape[2] - 1 if axis is None else int(axis)
    return f["time"][...], np.minimum.accumulate(x[:, :, ax].min(axis=1))
