#!/usr/bin/env python3
"""Genesis's own coupling examples, headless on the CPU, timed like ../shared/bench/genesis_bench.py.

Run it in Genesis's virtual environment (not simcli's; ../shared/bench/README.md):

    QD_NUM_THREADS=2 ~/genesis-venv/bin/python benchmarks/genesis_coupling_bench.py sph_mpm --steps 100
    QD_NUM_THREADS=2 ~/genesis-venv/bin/python benchmarks/genesis_coupling_bench.py sand_wheel --steps 200

SCENE is one of Genesis's examples/coupling/ scripts (genesis-world 1.4.5), copied with their options:

- ``sph_mpm``: examples/coupling/sph_mpm.py: an MPM elastic duck (rho 200, meshes/duck.obj scaled 0.07)
  dropped into a WCSPH water box (0.7 x 0.9 x 0.5 m, particle_size 0.02); MPM grid_density 64 on
  (0, 0, -0.1)-(1, 1, 1); dt 2e-3 with 10 substeps.
- ``sand_wheel``: examples/coupling/sand_wheel.py: MPM sand emitted from a 0.03 x 0.05 m nozzle at 8 m/s
  onto four paddle wheels (urdf/wheel/wheel.urdf scaled 0.6, on fixed axles, free to turn), a plane at
  z = 0; MPM grid_density 64 on (0, -1, -0.1)-(0.57, 1, 2.4); dt 3e-3 with 10 substeps. ``--sway 0``
  points the nozzle straight down every step (the example sways it in y by sin(i / 10) 0.35), as simcli's
  fixed emitter does.

Only the viewer is left out. Prints one line ``RESULT {json}``: import, build, first step, steady
substeps/s over the steps after ``--warm`` (each step timed; the emitter's ``emit`` is inside the timed
step, as in the example's loop), particle counts at the end, the wheels' angular velocities.
"""

import argparse
import json
import time

p = argparse.ArgumentParser()
p.add_argument("scene", choices=("sph_mpm", "sand_wheel"))
p.add_argument("--steps", type=int, default=100, help="steps timed after the warm-up")
p.add_argument("--warm", type=int, default=2, help="steps after the first left out of the timing")
p.add_argument("--max_s", type=float, default=300.0)
p.add_argument("--sway", type=int, default=0, help="sand_wheel: sway the nozzle as the example does")
args = p.parse_args()

T = {}
t0 = time.perf_counter()
import genesis as gs  # noqa: E402
import numpy as np  # noqa: E402

T["import_s"] = time.perf_counter() - t0
t0 = time.perf_counter()
gs.init(backend=gs.cpu, seed=0, precision="32", logging_level="warning")
T["gs_init_s"] = time.perf_counter() - t0
try:
    from quadrants.lang import impl as _impl

    threads = _impl.current_cfg().cpu_max_num_threads
except Exception:
    threads = None

info = dict(scene=args.scene, genesis=gs.__version__, threads=threads)
t0 = time.perf_counter()
ents, wheels, emit = {}, [], None
if args.scene == "sph_mpm":
    dt, sub = 2e-3, 10
    scene = gs.Scene(
        sim_options=gs.options.SimOptions(dt=dt, substeps=sub),
        mpm_options=gs.options.MPMOptions(lower_bound=(0.0, 0.0, -0.1), upper_bound=(1.0, 1.0, 1.0)),
        sph_options=gs.options.SPHOptions(lower_bound=(-0.03, -0.03, -0.08), upper_bound=(1.03, 1.03, 1.0)),
        show_viewer=False,
    )
    ents["water"] = scene.add_entity(
        morph=gs.morphs.Box(pos=(0.4, 0.5, 0.25), size=(0.7, 0.9, 0.5)), material=gs.materials.SPH.Liquid()
    )
    ents["duck"] = scene.add_entity(
        morph=gs.morphs.Mesh(
            file="meshes/duck.obj", pos=(0.5, 0.5, 0.7), scale=0.07, euler=(90.0, 0.0, 90.0)
        ),
        material=gs.materials.MPM.Elastic(rho=200),
    )
else:
    dt, sub = 3e-3, 10
    scene = gs.Scene(
        sim_options=gs.options.SimOptions(dt=dt, substeps=sub),
        mpm_options=gs.options.MPMOptions(
            lower_bound=(0.0, -1.0, -0.1), upper_bound=(0.57, 1.0, 2.4), grid_density=64
        ),
        show_viewer=False,
    )
    scene.add_entity(
        material=gs.materials.Rigid(needs_coup=True, coup_friction=0.2),
        morph=gs.morphs.URDF(file="urdf/plane/plane.urdf", fixed=True),
    )
    mat_wheel = gs.materials.Rigid(needs_coup=True, coup_softness=0.0)
    for pos in ((0.5, -0.2, 1.6), (0.5, 0.3, 1.2), (0.5, -0.3, 0.8), (0.5, 0.4, 0.4)):
        wheels.append(
            scene.add_entity(
                material=mat_wheel,
                morph=gs.morphs.URDF(
                    file="urdf/wheel/wheel.urdf",
                    pos=pos,
                    euler=(0, 0, 90),
                    scale=0.6,
                    convexify=False,
                    fixed=True,
                ),
            )
        )
    emitter = scene.add_emitter(material=gs.materials.MPM.Sand(), max_particles=200000)
    ents["sand"] = emitter

    def emit(i):
        d = np.array([0.0, np.sin(i / 10) * 0.35 if args.sway else 0.0, -1.0])
        emitter.emit(
            pos=np.array([0.5, 0.0, 2.3]),
            direction=d,
            speed=8.0,
            droplet_shape="rectangle",
            droplet_size=[0.03, 0.05],
        )


T["scene_setup_s"] = time.perf_counter() - t0
info.update(dt=dt, substeps=sub)
t0 = time.perf_counter()
scene.build(n_envs=0)
T["build_s"] = time.perf_counter() - t0
if "duck" in ents:  # where the duck's particles start (to place simcli's duck the same way)
    _p = ents["duck"].get_particles_pos()
    _p = (_p.cpu().numpy() if hasattr(_p, "cpu") else np.asarray(_p)).reshape(-1, 3)
    info.update(
        duck_start_min=[round(float(x), 4) for x in _p.min(0)],
        duck_start_max=[round(float(x), 4) for x in _p.max(0)],
    )

step_i = 0


def step():
    global step_i
    if emit is not None:
        emit(step_i)
    scene.step()
    step_i += 1


t0 = time.perf_counter()
step()
T["first_step_s"] = time.perf_counter() - t0
for _ in range(args.warm):
    step()
n = 0
t0 = time.perf_counter()
while n < args.steps and time.perf_counter() - t0 < args.max_s:
    step()
    n += 1
el = time.perf_counter() - t0
info.update({k: round(v, 3) for k, v in T.items()})
info.update(
    steady_steps=n,
    steps_total=step_i,
    steady_s=round(el, 3),
    steps_per_s=round(n / el, 3),
    substeps_per_s=round(n * sub / el, 2),
    sim_time_s=round(step_i * dt, 4),
)
counts = {}
for name, e in ents.items():
    try:
        if name == "sand":
            act = e._entity.get_particles_active() if hasattr(e._entity, "get_particles_active") else None
            counts["sand_capacity"] = int(e._entity.n_particles)
            counts["sand_emitted"] = int(e._next_particle)
            if act is not None:
                a = act.cpu().numpy() if hasattr(act, "cpu") else np.asarray(act)
                counts["sand_active"] = int((a > 0).sum())
        else:
            counts[name] = int(e.n_particles)
    except Exception as ex:  # reporting must not fail the timing
        counts[name + "_error"] = repr(ex)[:200]
info["counts"] = counts
if wheels:
    w = []
    for e in wheels:
        try:
            v = e.get_dofs_velocity()
            w.append(round(float(np.asarray(v.cpu() if hasattr(v, "cpu") else v).ravel()[-1]), 3))
        except Exception as ex:
            w.append(repr(ex)[:80])
    info["wheel_omega"] = w
try:
    src = ents.get("duck") or ents["sand"]._entity
    pos = src.get_particles_pos()
    pos = (pos.cpu().numpy() if hasattr(pos, "cpu") else np.asarray(pos)).reshape(-1, 3)
    info.update(finite=bool(np.isfinite(pos).all()))
    if "duck" in ents:
        info.update(
            duck_min=[round(float(x), 3) for x in pos.min(0)],
            duck_max=[round(float(x), 3) for x in pos.max(0)],
        )
except Exception as ex:
    info["sanity_error"] = repr(ex)[:200]
import resource  # noqa: E402

info["peak_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
print("RESULT " + json.dumps(info), flush=True)
