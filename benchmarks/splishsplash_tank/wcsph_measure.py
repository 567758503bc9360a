"""WCSPH tank measures of a SPlisHSPlasH run (run_tank.py output), with simcli's definitions
(simcli/verify/measure.py: bottom_pressure, wall_layer_pressure_ratio, mean_speed), over 2-3 s.
Usage: python wcsph_measure.py out_dir [out_dir ...]
The tank's effective walls are the lattice's outer edges (floor y = 0, side walls x = -/+0.1 m: the tuned
scenes put the first row and column half a particle size inside them). Pressure: the VTK 'pressure' field
(SPlisHSPlasH's WCSPH: p = k ((max(rho, rho0) / rho0)^n - 1))."""

import glob
import os
import sys

import numpy as np
from vtkread import read_vtk

rho0, g, ps = 1000.0, 9.81, 0.005
XW = 0.1  # effective side walls at x = -/+XW


def measures(x, y, p):
    z = y.copy()
    H = np.percentile(z, 99.5)
    band = (z >= 0.1 * H) & (z <= 0.8 * H)
    side = lambda m: (x < -XW + m) | (x > XW - m)
    _b, a0 = np.polyfit(z[band], p[band], 1)
    bi, ai0 = np.polyfit(z[band & ~side(2 * ps)], p[band & ~side(2 * ps)], 1)
    wall = (side(ps) & (z <= 0.8 * H)) | (z < ps)
    ratio = np.median(p[wall] / (ai0 + bi * z[wall]))
    return a0, ai0, ratio


for d in sys.argv[1:]:
    files = sorted(
        glob.glob(os.path.join(d, "vtk", "ParticleData_Fluid_*.vtk")),
        key=lambda s: int(s.rsplit("_", 1)[1][:-4]),
    )
    f = np.load(os.path.join(d, "frames.npz"))
    rows = []
    for k, fn in enumerate(files):
        t = float(f[f"{k}_t"])
        v = read_vtk(fn)
        x, y = v["position"][:, 0], v["position"][:, 1]
        sp = np.linalg.norm(v["velocity"], axis=1).mean()
        p = v["pressure"]
        p0, p0i, ratio = measures(x, y, p)
        rows.append((t, p0, p0i, ratio, sp, y.min(), np.abs(x).max()))
    print(f"== {d}")
    print("   t     floor p [Pa]  interior [Pa]  wall-layer ratio  mean speed [cm/s]  ymin [mm]  |x|max [mm]")
    for r in rows:
        print(
            f"  {r[0]:5.2f}  {r[1]:9.1f}  {r[2]:9.1f}  {r[3]:7.3f}  {100 * r[4]:8.3f}  {1000 * r[5]:7.2f}  "
            f"{1000 * r[6]:7.2f}"
        )
    w = np.array([r for r in rows if 2.0 - 1e-6 <= r[0] <= 3.0 + 1e-3])
    ref = rho0 * g * 0.1
    print(
        f"  2-3 s ({len(w)} frames): floor {w[:, 1].mean():.1f} Pa ({100 * (w[:, 1].mean() / ref - 1):+.2f}% "
        f"vs rho0 g H = {ref:.0f}), interior {w[:, 2].mean():.1f} Pa "
        f"({100 * (w[:, 2].mean() / ref - 1):+.2f}%), wall-layer ratio {w[:, 3].mean():.3f}, largest mean "
        f"speed {100 * w[:, 4].max():.3f} cm/s"
    )
