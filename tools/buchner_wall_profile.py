"""Where the pressure on the right wall of Buchner's 2D dam break sits
(configs/validation/sph_buchner_2d*.yaml; docs/VALIDATION.md, "Buchner").

For each run folder (a ``simcli run`` output with sim.h5, pressure probes on the right wall, frames with
position and pressure a few ms apart):

* per wall probe: the impulse error over T = t sqrt(g / H) in [2.0, 3.5] against the experiment's P1 (the
  verify metric ``impulse_rel``) and the mean P = p / (rho g H) over the window;
* per frame time in the window: the incoming layer's depth and speed at x = 2.8 and 3.0 m against Ritter's
  dam-break solution, the thickness of the liquid attached to the wall at several heights (the run-up jet),
  the height the wall-attached liquid reaches, and the pressure of the liquid particles next to the wall
  (within 1.5 particle sizes) per height band;
* a resolution-free estimate of the same wall pressure (``--theory``, also without runs): the incoming
  layer, d deep at speed U, turning up the wall in the corner as half of a plane jet 2d wide impinging
  normally on a plate (Kirchhoff's free streamlines, steady, inviscid, no gravity): along the wall
  y(q) = (4 d / pi) (artanh q + arctan q) and p = rho U^2 / 2 (1 - q^2), q the speed along the wall over U;
  fed with Ritter's depth and speed at the wall, and with each run's own layer at x = 3.0 m.

Usage: python tools/buchner_wall_profile.py [RUN ...] [--times 2.5 2.75 3.0 3.25 3.5] [--theory]
"""

import argparse
import sys
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from simcli.verify.reference import window_integral  # noqa: E402

H, G, RHO, L, X0 = 0.6, 9.81, 1000.0, 3.22, 1.2
TS = np.sqrt(G / H)  # T = t * TS
PN = RHO * G * H  # P = p / PN
REF = Path(__file__).resolve().parents[1] / "simcli/verify/reference_data/buchner2002_dam_break_2d_p1.csv"
HEIGHTS = (0.04, 0.08, 0.12, 0.16, 0.20, 0.30)
THEORY_HEIGHTS = (0.04, 0.08, 0.10, 0.12, 0.14, 0.16, 0.20)


def ritter(x, t):
    """Ritter's (1892) dam-break depth and speed at x, time t (dry bed, dam at X0, depth H behind it)."""
    c0 = np.sqrt(G * H)
    s = (x - X0) / t
    if s >= 2 * c0:
        return 0.0, 0.0
    return (4.0 / (9.0 * G)) * (c0 - s / 2) ** 2, (2.0 / 3.0) * (s + c0)


def jet_wall_pressure(y, d, u):
    """Kirchhoff's free-streamline wall pressure at height ``y`` [m] of a layer ``d`` deep at speed ``u``
    turning up a wall in a corner (half of a plane jet 2d wide impinging normally on a plate): the
    speed ratio q along the wall solves y = (4 d / pi) (artanh q + arctan q); p = rho u^2 / 2 (1 - q^2)."""
    if d <= 0.0 or u <= 0.0:
        return 0.0
    lo, hi = 0.0, 1.0 - 1e-15
    if 4.0 * d / np.pi * (np.arctanh(hi) + np.arctan(hi)) <= y:
        return 0.0
    for _ in range(64):  # bisection: the left side grows with q (2^-64 below double precision)
        mid = 0.5 * (lo + hi)
        if 4.0 * d / np.pi * (np.arctanh(mid) + np.arctan(mid)) < y:
            lo = mid
        else:
            hi = mid
    q = 0.5 * (lo + hi)
    return 0.5 * RHO * u * u * (1.0 - q * q)


def theory(i_exp, label, depth_speed):
    """The impulse error by height of the free-streamline wall pressure with the inflow ``depth_speed(t)``."""
    ts = np.linspace(2.0 / TS, 3.5 / TS, 601)
    row = []
    for y in THEORY_HEIGHTS:
        p = np.array([jet_wall_pressure(y, *depth_speed(t)) for t in ts]) / PN
        i = window_integral(ts * TS, p, 2.0, 3.5)
        row.append(f"y {y:.2f}: {100 * (i / i_exp - 1):+.0f} % (mean P {i / 1.5:.2f})")
    print(f"  free-streamline wall pressure, {label}: " + "; ".join(row))


def layer_at(f, dp, xc=3.0):
    """The run's incoming layer at x = ``xc`` per frame: (times, depth, mean horizontal speed)."""
    x, v, tf = f["entities/water/position"], f["entities/water/velocity"], f["time"][:]
    out = []
    for k in range(len(tf)):
        if not (1.9 < tf[k] * TS < 3.6):
            continue
        xy = x[k].astype(np.float64)
        col = np.abs(xy[:, 0] - xc) < dp
        top = contiguous_extent(xy[col, 1], 0.0, 2.5 * dp, +1) if col.any() else None
        d = 0.0 if top is None else top + dp / 2
        sel = col & (xy[:, 1] <= d)
        u = float(v[k][sel, 0].astype(np.float64).mean()) if sel.any() else 0.0
        out.append((tf[k], d, u))
    return np.array(out).T


def contiguous_extent(v, start, gap, direction):
    """From ``start`` along ``direction`` (+1 / -1), the far end of the run of sorted values ``v`` whose steps
    stay below ``gap``; None if the first value is already farther than ``gap`` from ``start``."""
    v = np.sort(v)[::-1] if direction < 0 else np.sort(v)
    last = start
    for a in v:
        if abs(a - last) > gap:
            break
        last = a
    return None if last == start else last


def frames(f, dp, times):
    x = f["entities/water/position"]
    p = f["entities/water/pressure"]
    tf = f["time"][:]
    for T in times:
        k = int(np.argmin(np.abs(tf * TS - T)))
        xy = x[k].astype(np.float64)
        pr = p[k].astype(np.float64)
        out = [f"  T {tf[k] * TS:.2f} (t {tf[k]:.3f} s):"]
        for xc in (2.8, 3.0):
            col = xy[np.abs(xy[:, 0] - xc) < dp]
            top = contiguous_extent(col[:, 1], 0.0, 2.5 * dp, +1) if len(col) else None
            depth = (top + dp / 2) if top is not None else 0.0
            u = col[col[:, 1] <= depth, 0] if len(col) else np.array([])
            hr, ur = ritter(xc, tf[k])
            vel = f["entities/water/velocity"][k].astype(np.float64)
            sel = (np.abs(xy[:, 0] - xc) < dp) & (xy[:, 1] <= depth)
            um = float(vel[sel, 0].mean()) if sel.any() and len(u) else float("nan")
            out.append(
                f"    x {xc}: layer {100 * depth:.1f} cm, u {um:.2f} m/s "
                f"(Ritter {100 * hr:.1f} cm, {ur:.2f} m/s)"
            )
        wall = xy[xy[:, 0] > L - 1.5 * dp]
        reach = contiguous_extent(wall[:, 1], 0.0, 2.5 * dp, +1) if len(wall) else None
        out.append(
            f"    wall-attached liquid reaches y = {reach if reach is None else round(reach + dp / 2, 3)} m"
        )
        row = []
        for y in HEIGHTS:
            band = xy[np.abs(xy[:, 1] - y) < dp]
            left = contiguous_extent(band[:, 0], L, 2.5 * dp, -1) if len(band) else None
            thick = 0.0 if left is None else L - left + dp / 2
            near = (np.abs(xy[:, 1] - y) < dp) & (xy[:, 0] > L - 1.5 * dp)
            pw = float(pr[near].mean()) / PN if near.any() else 0.0
            row.append(f"y {y:.2f}: {100 * thick:5.1f} cm, P {pw:5.2f}")
        out.append("    wall layer thickness and wall pressure: " + "; ".join(row))
        print("\n".join(out))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="*", type=Path)
    ap.add_argument("--times", nargs="*", type=float, default=[2.5, 2.75, 3.0, 3.25, 3.5])
    ap.add_argument("--theory", action="store_true", help="the free-streamline estimate (see the module doc)")
    a = ap.parse_args()
    ref = np.loadtxt(REF, delimiter=",", skiprows=2)
    i_exp = window_integral(ref[:, 0], ref[:, 1], 2.0, 3.5)
    if a.theory:
        theory(i_exp, "Ritter's layer at the wall (x = 3.22 m)", lambda t: ritter(L, t))
    for run in a.runs:
        with h5py.File(run / "sim.h5", "r") as f:
            n = f["entities/water/position"].shape[1]
            dp = np.sqrt(1.2 * H / n)
            print(f"{run}: {n} particles, particle size {dp * 1000:.2f} mm (H / {H / dp:.0f})")
            rows = []
            for name in f.get("probes", {}):
                t = f[f"probes/{name}/time"][:]
                v = np.nan_to_num(f[f"probes/{name}/value"][:])
                y = name
                e = window_integral(t * TS, v / PN, 2.0, 3.5) / i_exp - 1.0
                m = window_integral(t * TS, v / PN, 2.0, 3.5) / 1.5
                rows.append(f"{y} {100 * e:+.1f} % (mean P {m:.2f})")
            print("  probes, impulse error [T 2.0-3.5]: " + "; ".join(rows))
            print(f"  experiment at P1: mean P {i_exp / 1.5:.2f}")
            if "entities/water/pressure" in f and f["time"].shape[0] > 2:
                frames(f, dp, a.times)
                if a.theory:
                    tl, dl, ul = layer_at(f, dp)
                    theory(
                        i_exp,
                        "this run's layer at x = 3.0 m",
                        lambda t: (float(np.interp(t, tl, dl)), float(np.interp(t, tl, ul))),
                    )


if __name__ == "__main__":
    main()
