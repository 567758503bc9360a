"""Headless SPlisHSPlasH run of the 2D hydrostatic tank.
Usage: python run_tank.py scene.json outdir
Runs the scene (VTK export of particles every 0.1 s is done by SPlisHSPlasH itself into outdir/vtk),
and additionally logs per time step: t, dt, DFSPH pressure iterations, divergence iterations
(steps.csv), and, for every step in which SPlisHSPlasH wrote a VTK frame, dumps to frames.npz (time, dt of
that step, positions, velocity, density) -- dt is needed to convert the exported 'p / rho^2' to a pressure
(see measure.py). Env: SY=<factor> stretches the initial lattice vertically (y -> SY*y);
     VISC_SETTLE=<nu>:<t_end> optional viscous settling phase (not used for the reported runs).
Needs LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0 (the wheel's bundled libGLdispatch segfaults on
import)."""

import os
import shutil
import sys
import time

import numpy as np
import pysplishsplash as sph

scene = os.path.abspath(sys.argv[1])
out = os.path.abspath(sys.argv[2])
if os.path.exists(os.path.join(out, "vtk")):
    shutil.rmtree(os.path.join(out, "vtk"))
os.makedirs(out, exist_ok=True)
shutil.copy(scene, os.path.join(out, "scene.json"))
base = sph.Exec.SimulatorBase()
base.init(sceneFile=scene, useGui=False, initialPause=False, outputDir=out, useCache=False)
base.initSimulation()
sim = sph.Simulation.getCurrent()
fm = sim.getFluidModel(0)
tm = sph.TimeManager.getCurrent()
n = fm.numActiveParticles()
SY = float(os.environ.get("SY", "1"))  # optional vertical stretch of the initial lattice (y -> SY*y)
if SY != 1.0:
    for i in range(n):
        p = np.array(fm.getPosition(i))
        p[1] *= SY
        fm.setPosition(i, p)
    print(f"[driver] lattice stretched in y by {SY}", flush=True)
X0 = np.array([fm.getPosition(i) for i in range(n)])
print(
    f"[driver] sim2D={sim.is2DSimulation()} n={n} support={sim.getSupportRadius():.6g} "
    f"mass={fm.getMass(0):.6g} vol={fm.getVolume(0):.6g}",
    flush=True,
)
print(
    f"[driver] initial min={X0.min(0)} max={X0.max(0)} nx={len(np.unique(X0[:, 0].round(6)))} "
    f"ny={len(np.unique(X0[:, 1].round(6)))}",
    flush=True,
)

# optional settling phase: VISC_SETTLE="nu:t_end" -> kinematic viscosity nu until t_end, then the scene's
# value
visc = fm.getViscosityBase()
nu_scene = visc.getValueFloat(visc.VISCOSITY_COEFFICIENT)
print(f"[driver] viscosity method {fm.getViscosityMethod()}, coefficient {nu_scene}", flush=True)
settle = os.environ.get("VISC_SETTLE")
if settle:
    nu_s, t_s = map(float, settle.split(":"))
    visc.setValueFloat(visc.VISCOSITY_COEFFICIENT, nu_s)
    print(f"[driver] settling phase: viscosity {nu_s} until t = {t_s}, then {nu_scene}", flush=True)
steps = []
frames = {}


def cb():
    ts = sim.getTimeStep()
    t = tm.getTime()
    h = tm.getTimeStepSize()
    if settle and t >= t_s and visc.getValueFloat(visc.VISCOSITY_COEFFICIENT) != nu_scene:
        visc.setValueFloat(visc.VISCOSITY_COEFFICIENT, nu_scene)
        print(f"[driver] t = {t:.4f}: viscosity back to {nu_scene}", flush=True)
    its = [
        ts.getValueInt(getattr(ts, a)) if hasattr(ts, a) else 0
        for a in ("SOLVER_ITERATIONS", "SOLVER_ITERATIONS_V")
    ]
    steps.append((t, h, *its))  # WCSPH has no solver iterations (0)
    # SPlisHSPlasH has just exported VTK frame k+1 in this step (its own frame timing): record the state and
    # dt
    k = len(frames)
    if os.path.exists(os.path.join(out, "vtk", f"ParticleData_Fluid_{k + 1}.vtk")):
        frames[k] = dict(
            t=t,
            h=h,
            x=np.array([fm.getPosition(i) for i in range(n)]),
            v=np.array([fm.getVelocity(i) for i in range(n)]),
            rho=np.array([fm.getDensity(i) for i in range(n)]),
        )


base.setTimeStepCB(cb)
t0 = time.time()
base.runSimulation()
print(f"[driver] wall {time.time() - t0:.1f} s, steps {len(steps)}", flush=True)
np.savetxt(
    os.path.join(out, "steps.csv"),
    np.array(steps),
    delimiter=",",
    header="t,dt,iterations,iterationsV",
    comments="",
)
np.savez(
    os.path.join(out, "frames.npz"), **{f"{k}_{kk}": vv for k, d in frames.items() for kk, vv in d.items()}
)
base.cleanup()
