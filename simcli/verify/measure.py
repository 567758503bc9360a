"""Measurements: quantities extracted from a run's ``sim.h5``, each a time series.

Register a new one with ``@measurement("name")``; a function gets the open HDF5 file, the
entity name and the case's ``params``/``axis`` and returns ``(t, values)``.
"""

from __future__ import annotations

import math

import h5py
import numpy as np

# the registry and its helper live in a leaf module that the family measurement modules import too
from simcli.verify.registry import MEASUREMENTS, measurement  # noqa: F401  (MEASUREMENTS re-exported)
from simcli.verify.registry import entity_group as _entity
from simcli.verify.registry import scene_of as _scene_of  # noqa: F401 (measurement modules' helper)
from simcli.verify.registry import stack_field as _stack


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


@measurement("probe")
def probe(f, entity=None, name=None, axis=None, nan_as=None, **_):
    """A probe's time series as the run sampled it (sim.h5 /probes/<name>/time, /value; scene key `probes`);
    ``axis`` picks a component of a vector probe (default: its magnitude). ``entity`` is not used.
    ``nan_as``: the value of a dry sample (NaN: no particle in reach), e.g. 0 for a height gauge on a dry
    floor at z = 0; default: left NaN."""
    if name is None or "probes" not in f or name not in f["probes"]:
        have = ", ".join(f["probes"].keys()) if "probes" in f else "none"
        raise KeyError(f"probe '{name}' not in sim.h5 (probes: {have}); give params: {{name: <probe name>}}")
    g = f["probes"][name]
    n = min(g["time"].shape[0], g["value"].shape[0])
    t, v = g["time"][:n], np.asarray(g["value"][:n], dtype=np.float64)
    if v.ndim == 2:
        v = v[:, axis] if axis is not None else np.linalg.norm(v, axis=1)
    if nan_as is not None:
        v = np.where(np.isnan(v), float(nan_as), v)
    return t, v


@measurement("probe_mean")
def probe_mean(f, entity=None, names=None, **_):
    """The mean of several scalar probes' time series sampled at the same times (a sensor of finite size as
    probes along it, as TrixiParticles.jl reads its pressure sensors: the mean along a short line); a dry
    sample (NaN) counts as 0, as TrixiParticles' line sensor counts it. ``entity`` is not used."""
    if not names:
        raise KeyError("probe_mean needs params: {names: [<probe name>, ...]}")
    series = [probe(f, name=n, nan_as=0.0) for n in names]
    n = min(len(t) for t, _ in series)
    return series[0][0][:n], np.mean([v[:n] for _, v in series], axis=0)


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
    surface = (
        np.array([[np.median(zf[zf >= tf[0] - 0.5 * spacing])] for zf, tf in zip(z, top)]) + 0.5 * spacing
    )
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
        frame = frame[np.isfinite(frame).all(axis=1)]  # an emitter's unused capacity rows are NaN
        if len(frame) < 3:
            out.append(np.nan)
            continue
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
            d2 = ((xa[k : k + 512, None, :] - xb[None, :, :]) ** 2).sum(axis=2)
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


@measurement("tet_volume_ratio")
def tet_volume_ratio(f, entity, **_):
    """Total signed volume of a tetrahedral entity over its rest volume [-] (FEM). The rest positions are
    position - displacement of frame 0, so a body started deformed or inverted is measured against its rest
    shape."""
    _, g = _entity(f, entity)
    cells = np.asarray(g["cells"][...], dtype=np.int64)
    x = _positions(g)

    def vol(p):
        a = p[cells[:, 0]]
        return (
            np.einsum("ij,ij->", p[cells[:, 1]] - a, np.cross(p[cells[:, 2]] - a, p[cells[:, 3]] - a)) / 6.0
        )

    rest = x[0] - np.asarray(g["displacement"][0], dtype=np.float64)
    v0 = vol(rest)
    return f["time"][...], np.array([vol(xk) / v0 for xk in x])


@measurement("be_decay_ratio")
def be_decay_ratio(
    f,
    entity,
    w,
    axis=2,
    lower=None,
    upper=None,
    alpha=0.0,
    beta=0.0,
    skip=20,
    modes=2,
    scheme="backward_euler",
    **_,
):
    """Measured over predicted per-step decay of a vibration's slowest mode under backward Euler [-] (FEM
    implicit damping; output every step). The mean displacement along ``axis`` of the vertices initially in
    [lower, upper] after ``skip`` frames is fitted by linear prediction with ``modes`` damped modes and a
    constant (y_n+1 = sum_k a_k y_n-k + c: exact for a sum of modes of a linear one-step method); the root
    pair of smallest phase is the slowest mode, |lambda| its amplification per step. Backward Euler gives a
    mode of angular frequency ``w`` [rad/s] with Rayleigh damping c = alpha + beta w^2 the amplification
    (1 + dt c + (w dt)^2)^-1/2 (|1 / (1 + i w dt)| without damping). ``scheme: implicit_midpoint``: the
    midpoint rule's |(1 + dt m / 2) / (1 - dt m / 2)| with m = -c / 2 + i sqrt(w^2 - c^2 / 4) the mode's
    continuous root (no numerical damping: the decay is Rayleigh damping's alone; needs c > 0). Returns
    ln|lambda| / ln(prediction) at the last frame's time."""
    from simcli.verify.fem_measures import slowest_mode

    _, g = _entity(f, entity)
    t, dt, lam = slowest_mode(g, f["time"][...], lower, upper, axis, skip, modes, "be_decay_ratio")
    c = alpha + beta * w * w
    if scheme == "implicit_midpoint":
        mc = complex(-0.5 * c, math.sqrt(max(w * w - 0.25 * c * c, 0.0)))
        predicted = abs((1.0 + 0.5 * dt * mc) / (1.0 - 0.5 * dt * mc))
    elif scheme == "backward_euler":
        predicted = (1.0 + dt * c + (w * dt) ** 2) ** -0.5
    else:
        raise ValueError(f"be_decay_ratio: scheme {scheme!r}: give backward_euler or implicit_midpoint")
    if not predicted < 1.0:
        raise ValueError("be_decay_ratio: the predicted amplification is 1 (no damping): nothing to compare")
    return t[-1:], np.array([math.log(abs(lam)) / math.log(predicted)])


# ----------------------------------------------------------------------------- grid fluids (SF)


def _grid(f: h5py.File, entity: str | None, field: str = "velocity", frame: int | None = None):
    """(array of one frame or all frames, origin, spacing) of a grid entity's field; arrays are
    (..., nz, ny, nx[, c]) (x fastest), origin and spacing in x, y, z order."""
    _, g = _entity(f, entity)
    if g.attrs.get("kind") != "grid":
        raise TypeError(f"entity is a {g.attrs.get('kind')} entity, not a grid")
    d = g[field]
    a = np.asarray(d[...] if frame is None else d[frame], dtype=np.float64)
    return (
        a,
        np.asarray(g.attrs["origin"], dtype=np.float64),
        np.asarray(g.attrs["spacing"], dtype=np.float64),
    )


def _centres(origin, spacing, shape_xyz):
    return [origin[a] + (np.arange(shape_xyz[a]) + 0.5) * spacing[a] for a in range(len(shape_xyz))]


@measurement("centreline")
def centreline(f, entity, axis=None, component=0, along=1, at=0.5, frame=-1, **_):
    """Velocity component ``component`` along the line parallel to axis ``along`` through ``at`` (the
    other coordinate(s) [m]) in frame ``frame``: returns (coordinate along the line [m], velocity).
    The cell-centred values are interpolated linearly across the line (2D grids; a cavity's centrelines)."""
    v, o, h = _grid(f, entity, frame=frame)
    dim = v.ndim - 1
    if dim != 2:
        raise ValueError("centreline: 2D grids only")
    u = v[..., component].T  # (nx, ny): index order x, y
    xs = _centres(o, h, u.shape)
    across = 1 - along
    line = np.apply_along_axis(lambda col: np.interp(at, xs[across], col), across, u)
    return xs[along], line


def _stream_function(v, o, h):
    """psi at (x_i, y_{j+1/2}): the integral of u from the lower wall (psi = 0 there), 2D."""
    u = v[..., 0]  # (ny, nx)
    psi = np.cumsum(u, axis=0) * h[1]
    x = o[0] + (np.arange(u.shape[1]) + 0.5) * h[0]
    y = o[1] + (np.arange(u.shape[0]) + 1.0) * h[1]
    return psi, x, y


@measurement("vortex_centre")
def vortex_centre(f, entity, axis=0, kind="min", **_):
    """Coordinate ``axis`` [m] of the extremum (``kind``: min or max) of the stream function of the
    last frame, refined by a quadratic fit through the 3 x 3 neighbourhood (a cavity's primary vortex:
    min for a lid moving along +x). Returns (last time, coordinate)."""
    v, o, h = _grid(f, entity, frame=-1)
    psi, x, y = _stream_function(v, o, h)
    s = -psi if kind == "min" else psi
    j, i = np.unravel_index(np.argmax(s[1:-1, 1:-1]), (s.shape[0] - 2, s.shape[1] - 2))
    j, i = j + 1, i + 1
    w = s[j - 1 : j + 2, i - 1 : i + 2]
    # fit s = c0 + c1 X + c2 Y + c3 X^2 + c4 X Y + c5 Y^2 on the 3 x 3 stencil (X, Y in cells)
    X, Y = np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0])
    A = np.stack([np.ones(9), X.ravel(), Y.ravel(), X.ravel() ** 2, (X * Y).ravel(), Y.ravel() ** 2], axis=1)
    c = np.linalg.lstsq(A, w.ravel(), rcond=None)[0]
    H = np.array([[2 * c[3], c[4]], [c[4], 2 * c[5]]])
    try:
        dX, dY = np.clip(np.linalg.solve(H, -c[1:3]), -1.0, 1.0)
    except np.linalg.LinAlgError:
        dX = dY = 0.0
    pos = (x[i] + dX * h[0], y[j] + dY * h[1])
    return f["time"][-1:], np.array([pos[axis]])


@measurement("grid_kinetic_energy")
def grid_kinetic_energy(f, entity, rho=1.0, **_):
    """Kinetic energy 0.5 rho sum |u|^2 dV of a grid entity's cell velocities [J] (per metre in 2D)."""
    v, _, h = _grid(f, entity)
    return f["time"][...], 0.5 * rho * (v * v).sum(axis=tuple(range(1, v.ndim))) * float(np.prod(h))


@measurement("ke_decay_rate")
def ke_decay_rate(f, entity, **_):
    """Decay rate -d ln(KE)/dt [1/s] of a grid entity's kinetic energy between successive frames, at the
    interval midpoints (Taylor-Green: 4 nu, with the scheme's own numerical viscosity on top)."""
    t, ke = grid_kinetic_energy(f, entity)
    return 0.5 * (t[1:] + t[:-1]), -np.diff(np.log(ke)) / np.diff(t)


@measurement("numerical_viscosity")
def numerical_viscosity(f, entity, nu=0.0, k2=2.0, **_):
    """Effective viscosity [m^2/s] of a decaying single-mode flow, rate / (2 k^2), minus the physical
    ``nu`` (Taylor-Green: k^2 = 2 for u = sin x cos y)."""
    t, rate = ke_decay_rate(f, entity)
    return t, rate / (2.0 * k2) - nu


@measurement("grid_max_speed")
def grid_max_speed(f, entity, **_):
    """Largest cell speed [m/s] of a grid entity in each frame."""
    v, _, _ = _grid(f, entity)
    return f["time"][...], np.sqrt((v * v).sum(axis=-1)).reshape(len(v), -1).max(axis=1)


@measurement("grid_change_rate")
def grid_change_rate(f, entity, **_):
    """How fast a grid entity's velocity still changes: max over cells of |u(t_k) - u(t_k-1)| / (t_k - t_k-1)
    [m/s^2] between successive frames, at the later frame's time (a run-to-steady-state check)."""
    v, _, _ = _grid(f, entity)
    t = f["time"][...]
    d = np.abs(np.diff(v, axis=0)).reshape(len(v) - 1, -1).max(axis=1)
    return t[1:], d / np.diff(t)


@measurement("grid_field_drift")
def grid_field_drift(f, entity, field="density", **_):
    """Largest change of a grid entity's cell field ``field`` from its first frame, max over cells of
    |q(t) - q(0)|, in each frame (a state at rest must keep its smoke where it is)."""
    q, _, _ = _grid(f, entity, field)
    return f["time"][...], np.abs(q - q[0]).reshape(len(q), -1).max(axis=1)


@measurement("divergence_per_substep")
def divergence_per_substep(f, entity, **_):
    """Largest cell divergence times the substep, max |div u| dt [-] (the relative volume change of a cell
    in one substep), from the grid's `divergence` field and the run's dt and substeps."""
    import yaml

    d, _, _ = _grid(f, entity, "divergence")
    sim = yaml.safe_load(f.attrs["scene"])["sim"]
    sub = sim.get("substeps", 1)
    if not isinstance(sub, int):
        raise ValueError("divergence_per_substep needs a fixed sim.substeps")
    return f["time"][...], np.abs(d).reshape(len(d), -1).max(axis=1) * float(sim["dt"]) / sub


# ------------------------------------------------------------------ SPH validation measures


@measurement("bottom_pressure")
def bottom_pressure(f, entity, floor=0.0, axis=None, lo=0.1, hi=0.8, wall_margin=None, **_):
    """Pressure [Pa] at the ``floor`` of a liquid column at rest: a least-squares line p(z) through the
    particles between ``lo`` and ``hi`` of the column's height above the floor (away from the boundary
    layer and the free surface), evaluated at the floor. ``wall_margin`` [m]: also leave out the particles
    within that distance of the domain's side walls (their wall layer: with boundary particles the liquid
    next to a wall carries 1.7x the hydrostatic pressure, docs/SPH.md), so that the line is the interior
    field's alone."""
    import yaml

    x = _stack(f, entity)
    p = _stack(f, entity, "pressure")
    ax = x.shape[2] - 1 if axis is None else axis
    dom = yaml.safe_load(f.attrs["scene"])["domain"]
    out = []
    for xf, pf in zip(x, p):
        zf = xf[:, ax] - floor
        height = np.percentile(zf, 99.5)
        sel = (zf >= lo * height) & (zf <= hi * height)
        if wall_margin is not None:
            sel &= ~_near_side_wall(xf, dom, ax, wall_margin)
        if sel.sum() < 3:
            raise ValueError("bottom_pressure: too few particles in the fitting band")
        out.append(np.polyfit(zf[sel], pf[sel], 1)[1])
    return f["time"][...], np.asarray(out)


def _near_side_wall(x, dom, ax, margin):
    """Particles (rows of x) within ``margin`` of a domain wall across the vertical axis ``ax``."""
    out = np.zeros(len(x), bool)
    for a in range(x.shape[1]):
        if a != ax:
            out |= (x[:, a] < dom["lower"][a] + margin) | (x[:, a] > dom["upper"][a] - margin)
    return out


@measurement("wall_layer_pressure_ratio")
def wall_layer_pressure_ratio(f, entity, layer=None, axis=None, lo=0.1, hi=0.8, **_):
    """Median ratio of the pressure of the liquid's wall layer (the particles within ``layer`` [m] of a domain
    wall, default one particle size, at 10-80% of the depth, corners included) to the interior field's at
    their height (the line bottom_pressure fits, side walls' wall layers of two particle sizes left out): 1
    where the walls take the liquid's pressure without a wall-layer artefact (docs/SPH.md)."""
    import yaml

    scene = yaml.safe_load(f.attrs["scene"])
    dom = scene["domain"]
    ps = float(scene["solvers"]["sph"]["particle_size"])
    layer = ps if layer is None else layer
    x = _stack(f, entity)
    p = _stack(f, entity, "pressure")
    ax = x.shape[2] - 1 if axis is None else axis
    out = []
    for xf, pf in zip(x, p):
        zf = xf[:, ax] - dom["lower"][ax]
        height = np.percentile(zf, 99.5)
        band = (zf >= lo * height) & (zf <= hi * height)
        interior = band & ~_near_side_wall(xf, dom, ax, 2 * ps)
        b, a0 = np.polyfit(zf[interior], pf[interior], 1)
        wall = (_near_side_wall(xf, dom, ax, layer) & (zf <= hi * height)) | (zf < layer)
        with np.errstate(invalid="ignore", divide="ignore"):  # the first frame: no pressure yet (nan)
            out.append(np.median(pf[wall] / (a0 + b * zf[wall])))
    return f["time"][...], np.asarray(out)


@measurement("mean_speed")
def mean_speed(f, entity, **_):
    """Mean particle speed [m/s] (drift of a liquid that should be at rest)."""
    v = _stack(f, entity, "velocity")
    return f["time"][...], np.linalg.norm(v, axis=2).mean(axis=1)


@measurement("solver_report")
def solver_report(f, entity=None, path=(), **_):
    """A number from the run's run.json (next to sim.h5), by its key ``path`` (e.g. ``[solvers, sph,
    dfsph, density, average_error_percent_max]``), as a one-point series at the final time: figures
    per substep that no frame holds (DFSPH's worst average density error over every substep)."""
    import json
    from pathlib import Path

    info = json.loads((Path(f.filename).parent / "run.json").read_text())
    for key in path:
        info = info[key]
    t = f["time"][...]
    return t[-1:], np.asarray([float(info)])


@measurement("kinetic_energy_decay_rate")
def kinetic_energy_decay_rate(f, entity, t0=0.0, **_):
    """Decay rate [1/s] of the kinetic energy (equal particle masses): -ln(KE(t) / KE(t0)) / (t - t0)
    for t > t0 (Taylor-Green: 4 nu for a vortex of unit wavenumber)."""
    v = _stack(f, entity, "velocity")
    t = f["time"][...]
    ke = (v * v).sum(axis=2).mean(axis=1)
    k0 = int(np.argmin(np.abs(t - t0)))
    sel = t > t[k0] + 1e-12
    return t[sel], -np.log(ke[sel] / ke[k0]) / (t[sel] - t[k0])


@measurement("column_height")
def column_height(f, entity, width, axis=0, up=None, wall=0.0, q=99.0, spacing=0.0, **_):
    """Residual height [m] of a collapsing column at its back ``wall``: the q-th percentile of the
    height of the particles within ``width`` [m] of the wall along ``axis``, plus half a ``spacing``."""
    x = _stack(f, entity)
    up = x.shape[2] - 1 if up is None else up
    out = []
    for xf in x:
        sel = np.abs(xf[:, axis] - wall) <= width
        out.append(np.percentile(xf[sel, up], q) + 0.5 * spacing if sel.sum() else 0.0)
    return f["time"][...], np.asarray(out)


# ------------------------------------------------------------------ Coulomb friction (sliding)


def _along(f, entity, direction, field):
    """Mean of ``field`` (particles of one entity carry equal mass: the centre of mass for
    positions, its velocity for velocities) projected on the unit ``direction``."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    return _stack(f, entity, field).mean(axis=1) @ d


@measurement("slide_distance")
def slide_distance(f, entity, direction=(1.0, 0.0), **_):
    """Displacement [m] of the centre of mass along ``direction`` since the first frame."""
    s = _along(f, entity, direction, "position")
    return f["time"][...], s - s[0]


@measurement("slide_velocity")
def slide_velocity(f, entity, direction=(1.0, 0.0), **_):
    """Velocity [m/s] of the centre of mass along ``direction`` (the mean particle velocity)."""
    return f["time"][...], _along(f, entity, direction, "velocity")


@measurement("slide_stop_time")
def slide_stop_time(f, entity, direction=(1.0, 0.0), level=0.1, **_):
    """Time [s] a sliding body stops: where its centre-of-mass velocity along ``direction``,
    extrapolated from the last stretch above ``level`` times the initial speed (a straight line
    through the frames between that level and 0.6 of the initial speed), reaches zero. A body
    under Coulomb friction decelerates uniformly, so the line is its velocity; fitting it away
    from the stop avoids the frame rate's resolution and the elastic ringing of a stopped body.
    Every entry of the returned series is that one time (NaN while the body has not slowed)."""
    t = np.asarray(f["time"][...], dtype=np.float64)
    v = _along(f, entity, direction, "velocity")
    v0 = v[0]
    below = np.nonzero(v < level * v0)[0]
    stop = np.nan
    if len(below):
        k = below[0]
        sel = (np.arange(len(v)) < k) & (v <= 0.6 * v0)
        if sel.sum() >= 2:
            slope, icpt = np.polyfit(t[sel], v[sel], 1)
            if slope < 0:
                stop = -icpt / slope
    return t, np.full(len(t), stop)


# the PBD family's measurements register themselves in MEASUREMENTS on import
from simcli.verify import cloth_measures as _cloth_measures  # noqa: E402,F401
from simcli.verify import coupling_measures as _coupling_measures  # noqa: E402,F401
from simcli.verify import cpic_measures as _cpic_measures  # noqa: E402,F401
from simcli.verify import fem_measures as _fem_measures  # noqa: E402,F401
from simcli.verify import pbd_measures as _pbd_measures  # noqa: E402,F401
from simcli.verify import rigid_measures as _rigid_measures  # noqa: E402,F401

# ------------------------------------------------------------------ colliders (forces, penetration)


@measurement("collider_force")
def collider_force(f, entity, collider, axis=None, component="force", **_):
    """Force [N] (or with ``component: torque``, torque [N m]) the materials exert on the named collider
    (sim.h5 /colliders/<name>/...), one ``axis`` or the magnitude."""
    if "colliders" not in f or collider not in f["colliders"]:
        have = ", ".join(f["colliders"].keys()) if "colliders" in f else "none"
        raise KeyError(f"collider '{collider}' has no loads in sim.h5 (named colliders: {have})")
    d = np.asarray(f["colliders"][collider][component][...], dtype=np.float64)
    n = min(len(d), len(f["time"]))
    v = np.linalg.norm(d[:n], axis=1) if axis is None else d[:n, axis]
    return f["time"][:n], v


@measurement("collider_penetration")
def collider_penetration(f, entity, collider, spacing=None, scene_dir=None, **_):
    """Deepest particle of ``entity`` (``"*"``: every entity) inside the named collider at each frame [m],
    in units of ``spacing`` when given (e.g. the MPM cell size): the collider's exact signed distance at
    its pose at the frame's time (simcli.motion), 0 when no particle is inside. A Mesh collider: the exact
    distance to its triangles (not its signed-distance grid) of the particles inside it (ray parity);
    its file is relative to ``scene_dir`` (verify passes the case's folder)."""
    from simcli.colliders import _collider_spec
    from simcli.colliders import sdf_np as sdf_numpy
    from simcli.motion import collider_motion

    scene = _scene_of(f)
    dim = scene.sim.dim
    c = next((c for c in scene.colliders if c.name == collider), None)
    if c is None:
        raise KeyError(f"no collider named '{collider}' in the run's scene")
    if c.type == "Mesh":
        from simcli.collider_mesh import exact_depth

        motion = collider_motion(c, dim)
        x = _stack(f, entity)
        t = f["time"][...]
        out = [
            exact_depth(c, xi if motion is None else motion.pose(float(ti)).to_body(xi), scene, scene_dir)
            for ti, xi in zip(t, x)
        ]
        out = np.asarray(out)
        return t, out / spacing if spacing else out
    spec = _collider_spec(c, dim)
    motion = collider_motion(c, dim)
    x = _stack(f, entity)
    t = f["time"][...]
    out = []
    for ti, xi in zip(t, x):
        xb = xi if motion is None else motion.pose(float(ti)).to_body(xi)
        out.append(max(0.0, -float(sdf_numpy(spec, xb).min())))
    out = np.asarray(out)
    return t, out / spacing if spacing else out


# emitters and sinks (emitted and removed mass, a draining tank's level and jet)
from simcli.verify import source_measures as _source_measures  # noqa: E402,F401
