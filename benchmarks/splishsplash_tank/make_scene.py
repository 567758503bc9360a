"""Generate the SPlisHSPlasH 2D hydrostatic-tank scenes (run: python make_scene.py).

Fluid: FluidBlock of 40 x 20 particles, spacing 5 mm (particleRadius r = 2.5 mm),
centres x in [-0.0975, 0.0975], y in [0.0025, 0.0975] (y = 0 is the requested floor).
Container: UnitBox.obj (unit cube) scaled/translated; `gap` = distance from the outermost particle
centres to the mesh walls and floor, `sy` = vertical stretch of the lattice applied by run_tank.py
(env SY; 1 = none), so the mesh floor is at y = r*sy - gap.

  *_spec   : gap = r = 2.5 mm, sy = 1 -> mesh inner size exactly 0.2 x 0.2 m, floor at y = 0 (as requested)
  *_tuned  : gap = SPlisHSPlasH's equilibrium wall distance (Akinci2012 5.57 mm, volume map: calibrated),
             and the lattice stretched by sy = 1.000851 so that its SPH density is exactly rho0
             (the 5 mm lattice's 2D cubic-kernel sum is 1.00086 rho0 with V = (2r)^2).
             The 'effective floor' r*sy below the first row is at y = 0.
"""

import json
import sys

r = 0.0025
SY = 1.0008514038524843


def scene(bhm, gap, dtmax=0.0005, sy=1.0, init_dt=0.0001, stop=3.0, fps=10):
    width = 0.195 + 2 * gap
    yfloor = r * sy - gap  # mesh floor
    ytop = 0.2
    cfg = {
        "pause": False,
        "sim2D": True,
        "particleRadius": r,
        "simulationMethod": 4,
        "gravitation": [0, -9.81, 0],
        "timeStepSize": init_dt,
        "cflMethod": 1,
        "cflFactor": 1,
        "cflMaxTimeStepSize": dtmax,
        "stopAt": stop,
        "boundaryHandlingMethod": bhm,
        "enableVTKExport": True,
        "enablePartioExport": False,
        "dataExportFPS": fps,
        "particleAttributes": "velocity;density;p / rho^2;pressure acceleration",
        "DFSPH": {
            "minIterations": 2,
            "maxIterations": 100,
            "maxError": 0.01,
            "maxIterationsV": 100,
            "maxErrorV": 0.1,
            "enableDivergenceSolver": True,
        },
    }
    if init_dt is None:
        del cfg["timeStepSize"]
    return {
        "Configuration": cfg,
        "Materials": [
            {"id": "Fluid", "density0": 1000, "viscosityMethod": 1, "Standard viscosity": {"viscosity": 5e-5}}
        ],
        "RigidBodies": [
            {
                "geometryFile": "UnitBox.obj",
                "translation": [0, round((yfloor + ytop) / 2, 8), 0],
                "rotationAxis": [1, 0, 0],
                "rotationAngle": 0,
                "scale": [round(width, 8), round(ytop - yfloor, 8), 0.2],
                "isDynamic": False,
                "isWall": True,
                "mapInvert": True,
                "mapThickness": 0.0,
                "mapResolution": [40, 40, 20],
            }
        ],
        "FluidBlocks": [
            {
                "denseMode": 0,
                "start": [-0.1025, -0.0025, -0.1],
                "end": [0.1025, 0.1025, 0.1],
                "translation": [0, 0, 0],
                "scale": [1, 1, 1],
            }
        ],
    }


def wcsph(bhm, gap, dt):
    """The tuned tank with SPlisHSPlasH's WCSPH (simulationMethod 0) at simcli's WCSPH defaults (Tait k = 50
    kPa, n = 7) and a fixed step dt (simcli's automatic step on this tank: about 0.1 ms). SPlisHSPlasH's WCSPH
    walls
    push with the particle's pressure mirrored, (p_i / rho_i^2 + p_i / rho0^2) (TimeStepWCSPH.cpp)."""
    sc = scene(bhm, gap, sy=SY, dtmax=dt, init_dt=dt)
    c = sc["Configuration"]
    c["simulationMethod"] = 0
    del c["DFSPH"]
    c["stiffness"], c["exponent"] = 50000, 7
    c["particleAttributes"] = "velocity;density;pressure"
    return sc


GAP_AKINCI = 0.00557
GAP_VOLMAP = float(sys.argv[1]) if len(sys.argv) > 1 else 0.00548  # calibrated with calib.py


def write(name, sc):
    json.dump(sc, open(name, "w"), indent=2)


if __name__ == "__main__":
    # as requested, with a 0.5 ms time-step cap (SPlisHSPlasH's default cap 5 ms blows up, see *_dt5e-3)
    write("tank2d_akinci_spec.json", scene(0, r))
    write("tank2d_volmap_spec.json", scene(2, r))
    # as requested with SPlisHSPlasH's default time-step settings (initial 1 ms, cap 5 ms): exactly what was
    # run
    write("tank2d_akinci_spec_dt5e-3.json", scene(0, r, dtmax=0.005, init_dt=None))
    write("tank2d_volmap_spec_dt5e-3.json", scene(2, r, dtmax=0.005, init_dt=None))
    # tuned start (run with SY=1.0008514038524843)
    write("tank2d_akinci_tuned.json", scene(0, GAP_AKINCI, sy=SY))
    write("tank2d_volmap_tuned.json", scene(2, GAP_VOLMAP, sy=SY))
    # time-step sensitivity of the tuned start: cap (and initial step) 1, 2 ms and SPlisHSPlasH's default cap
    # 5 ms
    for dt in (0.001, 0.002, 0.005):
        write(f"tank2d_akinci_tuned_dt{dt:g}.json", scene(0, GAP_AKINCI, sy=SY, dtmax=dt, init_dt=dt))
    write("tank2d_volmap_tuned_dt0.005.json", scene(2, GAP_VOLMAP, sy=SY, dtmax=0.005, init_dt=0.005))
    # WCSPH (measured with wcsph_measure.py -> results_wcsph.txt)
    write("tank2d_wcsph_akinci_tuned.json", wcsph(0, GAP_AKINCI, 0.0001))
    write("tank2d_wcsph_akinci_tuned_dt5e-5.json", wcsph(0, GAP_AKINCI, 0.00005))
    write("tank2d_wcsph_volmap_tuned.json", wcsph(2, GAP_VOLMAP, 0.0001))
