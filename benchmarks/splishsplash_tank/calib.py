"""Initial SPH densities SPlisHSPlasH computes for the (stretched) lattice next to the walls, for a given
boundary method and wall gap: one step of 1e-7 s, density of frame 1 (computed from the initial positions)."""

import json
import os
import subprocess
import sys

import numpy as np
from make_scene import SY, scene
from vtkread import read_vtk

bhm = int(sys.argv[1])
gap = float(sys.argv[2])
sy = float(sys.argv[3]) if len(sys.argv) > 3 else SY
name = f"calib_{bhm}_{gap}"
json.dump(scene(bhm, gap, sy=sy, init_dt=1e-7, stop=5e-8), open(name + ".json", "w"), indent=1)
env = dict(os.environ, SY=str(sy))
subprocess.run(
    [sys.executable, "run_tank.py", name + ".json", "calib_out/" + name],
    env=env,
    capture_output=True,
    check=True,
)
d = read_vtk(f"calib_out/{name}/vtk/ParticleData_Fluid_1.vtk")
x, rho = d["position"], d["density"]
row = np.round((x[:, 1] / sy - 0.0025) / 0.005).astype(int)
col = np.round((x[:, 0] + 0.0975) / 0.005).astype(int)
mid = np.abs(x[:, 0]) < 0.05
print(
    f"bhm {bhm} gap {gap}: floor row {rho[(row == 0) & mid].mean():.2f}  row1 "
    f"{rho[(row == 1) & mid].mean():.2f}  interior "
    f"{rho[mid & (x[:, 1] > 0.03) & (x[:, 1] < 0.07)].mean():.3f}  side col "
    f"{rho[(col == 0) & (x[:, 1] > 0.02) & (x[:, 1] < 0.07)].mean():.2f}  max {rho.max():.1f} at row "
    f"{row[rho.argmax()]} col {col[rho.argmax()]}; top-2 {np.sort(rho)[-3:]}"
)
os.remove(name + ".json")
