"""Floor-pressure measurement of the SPlisHSPlasH 2D tank runs (simcli's procedure).
Usage: python measure.py out_dir [out_dir ...]
Needs: out_dir/vtk/ParticleData_Fluid_<k>.vtk (SPlisHSPlasH VTK export, 10 fps), out_dir/frames.npz (time and
time-step size of each exported frame, written by run_tank.py), out_dir/steps.csv (per-step solver
iterations), and the scene (out_dir/scene.json, copied by run_tank.py) for the floor position.

Pressure: SPlisHSPlasH's DFSPH exports the field 'p / rho^2' = X * dt^2 (warm start build: the solver's value
is multiplied by dt^2 at the end of each step), where X is the solver's p_i/rho_i^2 in units in which the
particle volume V_j (not the mass m_j = rho0 V_j) enters the pressure acceleration a_i = -sum_j V_j (X_i +
X_j) gradW_ij. Since m_j = rho0 V_j, X_i = rho0 p_i / rho_i^2, i.e. p_i = X_i rho_i^2 / rho0 [Pa] with X_i =
exported / dt^2 (dt = the step that produced the frame; ~ rho0 X_i since rho_i ~ rho0). (Cross-check printed:
the line slope against rho0 g, and the pressure acceleration.)
"""

import glob
import json
import os
import sys

import numpy as np
from vtkread import read_vtk

rho0, g = 1000.0, 9.81


def floors(scene):
    rb = scene["RigidBodies"][0]
    y_mesh = rb["translation"][1] - rb["scale"][1] / 2
    return y_mesh


def run(d):
    scene = json.load(open(os.path.join(d, "scene.json")))
    y_mesh = floors(scene)
    x_half = scene["RigidBodies"][0]["scale"][0] / 2
    y_eff = 0.0  # effective floor: r below the initial first row (y = 0 by construction)
    f = np.load(os.path.join(d, "frames.npz"))
    nfr = len(glob.glob(os.path.join(d, "vtk", "*.vtk")))
    steps = np.loadtxt(os.path.join(d, "steps.csv"), delimiter=",", skiprows=1)
    rows = []
    for k in range(nfr):
        t = float(f[f"{k}_t"])
        h = float(f[f"{k}_h"])
        v = read_vtk(os.path.join(d, "vtk", f"ParticleData_Fluid_{k + 1}.vtk"))
        assert np.allclose(v["position"], f[f"{k}_x"], atol=1e-6)
        x, y = v["position"][:, 0], v["position"][:, 1]
        inside = (np.abs(x) <= x_half + 1e-9) & (y >= y_mesh - 1e-9) & (y <= 0.2 + 1e-9)
        rho = v["density"]
        X = v["p_/_rho^2"] / h**2
        p = X * rho**2 / rho0
        sp = np.linalg.norm(v["velocity"], axis=1)
        res = dict(
            t=t,
            h=h,
            n_in=int(inside.sum()),
            speed=sp[inside].mean(),
            derr=((rho[inside] - rho0) / rho0).mean(),
            ay=np.median(v["pressure_acceleration"][inside, 1]),
        )
        for tag, y0 in (("eff", y_eff), ("mesh", y_mesh)):
            z = y[inside] - y0
            pp = p[inside]
            H = np.percentile(z, 99.5)
            m = (z >= 0.1 * H) & (z <= 0.8 * H)
            a, b = np.polyfit(z[m], pp[m], 1)
            res[tag] = dict(H=H, p0=b, slope=a)
            if tag == "eff":
                res["derr_band"] = ((rho[inside][m] - rho0) / rho0).mean()
                res["p0_rho0"] = np.polyfit(z[m], X[inside][m] * rho0, 1)[1]  # same fit with p = rho0 X
        rows.append(res)
    return rows, steps, y_mesh


if __name__ == "__main__":
    for d in sys.argv[1:]:
        rows, steps, y_mesh = run(d)
        w = [r for r in rows if 2.0 - 1e-6 <= r["t"] <= 3.0 + 1e-3]
        st = steps[(steps[:, 0] > 2.0) & (steps[:, 0] <= 3.0)]
        print(
            f"== {d}  (mesh floor y = {y_mesh * 1000:+.2f} mm, effective floor y = 0; {len(w)} frames in 2-3 "
            "s)"
        )
        print(
            "   t      n_in  H_eff[mm] p0_eff[Pa] p0_mesh[Pa] slope/(rho0 g) speed[cm/s] mean drho/rho0  "
            "a_p,y"
        )
        for r in rows[::5] + [rows[-1]]:
            print(
                f"  {r['t']:6.3f} {r['n_in']:4d}  {1000 * r['eff']['H']:7.2f}  {r['eff']['p0']:9.1f}  "
                f"{r['mesh']['p0']:9.1f}   {r['eff']['slope'] / (rho0 * g):7.4f}     {100 * r['speed']:7.3f} "
                f"   {100 * r['derr']:+.4f}%  {r['ay']:6.2f}"
            )
        P = np.array([r["eff"]["p0"] for r in w])
        Pm = np.array([r["mesh"]["p0"] for r in w])
        S = np.array([r["eff"]["slope"] for r in w]) / (rho0 * g)
        se = P.std(ddof=1) / np.sqrt(len(P))
        print(
            f"  2-3 s: floor p (effective floor) {P.mean():.1f} +- {se:.1f} Pa "
            f"({100 * (P.mean() / 981 - 1):+.2f}% vs 981; frame std {P.std(ddof=1):.1f}, spread "
            f"{P.min():.0f}..{P.max():.0f})"
        )
        print(
            f"         floor p (mesh floor)      {Pm.mean():.1f} Pa ({100 * (Pm.mean() / 981 - 1):+.2f}% vs "
            "981)"
        )
        print(f"         same fit with p = rho0*X: {np.mean([r['p0_rho0'] for r in w]):.1f} Pa")
        print(
            f"         slope/(rho0 g) {S.mean():.4f}; speed {100 * np.mean([r['speed'] for r in w]):.3f} "
            f"cm/s; mean density error {100 * np.mean([r['derr'] for r in w]):+.4f}% (fit band "
            f"{100 * np.mean([r['derr_band'] for r in w]):+.4f}%)"
        )
        print(
            f"         H(3 s) eff {1000 * rows[-1]['eff']['H']:.2f} mm, mesh "
            f"{1000 * rows[-1]['mesh']['H']:.2f} mm; iterations/step 2-3 s: {st[:, 2].mean():.2f} (div "
            f"{st[:, 3].mean():.2f}), whole run {steps[:, 2].mean():.2f}; dt mean 2-3 s "
            f"{st[:, 1].mean() * 1000:.3f} ms; particles in box {rows[-1]['n_in']}/800"
        )
