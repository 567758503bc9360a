"""Diagnostics of Buchner's 2D dam break runs (configs/validation/sph_buchner_2d.yaml; docs/VALIDATION.md).

For each run folder (a ``simcli run`` output with sim.h5):

* each pressure probe's impulse error over T = t sqrt(g / H) in [2.0, 3.5] against the experiment's P1 (the
  verify metric ``impulse_rel``), on all samples and on each phase of a subsampling to 5 ms (how much the
  sampling alone moves it);
* with ``--balance`` (needs frames with position, velocity and pressure, a few ms apart): per window of 0.4
  in T, the right wall's impulse from the liquid's momentum balance (dP_x/dt = F_left - F_right, F_left from
  the pressure at the left wall) against the integral of the written pressure along the right wall.

Usage: python tools/buchner_p1_diagnostics.py RUN [RUN ...] [--balance]
"""

import argparse
import sys
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from simcli.verify.reference import window_integral  # noqa: E402

H, G, RHO, L = 0.6, 9.81, 1000.0, 3.22
TS = np.sqrt(G / H)  # T = t * TS
PN = RHO * G * H  # P = p / PN
REF = Path(__file__).resolve().parents[1] / "simcli/verify/reference_data/buchner2002_dam_break_2d_p1.csv"


def rel(t_dimless, p_dimless, i_exp):
    return window_integral(t_dimless, p_dimless, 2.0, 3.5) / i_exp - 1.0


def probes(f, i_exp):
    for name in f.get("probes", {}):
        t = f[f"probes/{name}/time"][:]
        p = np.nan_to_num(f[f"probes/{name}/value"][:])
        k = max(1, round(0.005 / (t[1] - t[0])))
        phases = " ".join(f"{rel(t[o::k] * TS, p[o::k] / PN, i_exp):+.3f}" for o in range(k)) if k > 1 else ""
        print(f"  probe {name}: impulse error {rel(t * TS, p / PN, i_exp):+.3f}; 5 ms phases: {phases}")


def balance(f):
    t = f["time"][:]
    x, v, p = (f[f"entities/water/{q}"] for q in ("position", "velocity", "pressure"))
    dx = float(np.min(np.abs(np.diff(np.unique(np.round(x[0][:, 0], 6))))))  # the initial lattice spacing
    m = RHO * dx * dx
    px = np.array([v[i][:, 0].sum() * m for i in range(len(t))])
    fl, fr = np.zeros(len(t)), np.zeros(len(t))
    for i in range(len(t)):
        xi, pi = x[i], p[i]
        fl[i] = pi[xi[:, 0] < 2 * dx].sum() * dx / 2  # two columns, each particle a dy of dx
        fr[i] = pi[xi[:, 0] > L - 2 * dx].sum() * dx / 2
    for a in (2.0, 2.4, 2.8, 3.2):
        b = a + 0.4
        sel = np.flatnonzero((t * TS >= a) & (t * TS <= b))
        if len(sel) < 3:
            continue
        ts = t[sel]
        il = np.trapezoid(fl[sel], ts)
        print(
            f"  T {a:.1f}-{b:.1f}: right wall impulse from momentum {il - (px[sel[-1]] - px[sel[0]]):7.1f}, "
            f"from its pressure {np.trapezoid(fr[sel], ts):7.1f} N s/m"
        )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--balance", action="store_true")
    a = ap.parse_args()
    e = np.loadtxt(REF, delimiter=",", comments="#", skiprows=2)
    i_exp = window_integral(e[:, 0], e[:, 1], 2.0, 3.5)
    for run in a.runs:
        print(run)
        with h5py.File(Path(run) / "sim.h5") as f:
            probes(f, i_exp)
            if a.balance:
                balance(f)


if __name__ == "__main__":
    main()
