#!/usr/bin/env python3
"""FEM.Cloth beside Newton's VBD cloth (self-contact on) on the same machine and one thread: speed against
error on one scene. The sheet of benchmarks/cloth_bench.py (1 m x 1 m, n x n cells, 0.2 kg/m^2, 5 mm above a
sphere of radius 0.25 m, floor below) with the same membrane (mu t and lambda t of E = 1 MPa, nu = 0.3,
t = 0.5 mm), bending stiffness (D = E t^3 / 12 (1 - nu^2), Newton's hinge k L theta^2 / 2 with k = 2 D / h)
and friction 0.3; each code with its own step: Newton's cloth examples' setting (10 substeps of 1/600 s,
--iterations VBD sweeps each), simcli's FEM.Cloth at 1e-2 s (backward Euler, Newton to its tolerances, IPC
contact with CCD).

Error: the sheet's mean height at the end (--duration) against each code's own converged limit, since the two
models differ in their contact (VBD: a penalty on the shapes and a 2 mm self-contact offset; simcli: IPC's
barrier within 2 mm): simcli's limit is FEM.Cloth at Newton's step of 1/600 s (skipped with
--no-reference), Newton's its run at the most iterations listed. Also the intersections of the final mesh
by simcli's independent edge-triangle test, for both. Speed: simulated seconds per wall second of stepping
(the fair figure when the steps differ) and substeps per second.

Newton (pip ``newton``, Warp on the CPU, one thread) runs in its own environment, in a subprocess::

    python3 -m venv ~/newton-venv && ~/newton-venv/bin/pip install newton warp-lang   # Newton 1.8, Warp 1.19
    PYTHONPATH=. python benchmarks/cloth_vs_newton.py --newton-python ~/newton-venv/bin/python \\
        --cells 32 --iterations 10,20,40,80 --out docs/PERFORMANCE_CLOTH.md

simcli's host libraries are held to one thread (ipctk's pool, OMP / BLAS variables set before numpy loads).
FEM.Cloth factors with what ``solvers.fem.linear_solver: auto`` picks (CHOLMOD where the ``cholmod`` extra is
installed, else SuperLU; the row's label says which); ``--simcli-set solvers.fem.linear_solver=superlu``
adds a SuperLU run.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

E, NU, T, RHO = 1.0e6, 0.3, 5.0e-4, 400.0
MU_T = E * T / (2 * (1 + NU))  # membrane Lame parameters times thickness [N/m] (plane stress)
LAM_T = E * NU * T / (1 - NU**2)
D = E * T**3 / (12 * (1 - NU**2))  # bending stiffness [N m]


def run_newton(n: int, duration: float, substeps: int, iterations: int, out: str) -> None:
    import newton
    import numpy as np
    import warp as wp

    wp.config.quiet = True
    wp.set_device("cpu")
    b = newton.ModelBuilder()
    b.add_ground_plane()
    b.add_shape_sphere(body=-1, xform=wp.transform((0.0, 0.0, 0.3), wp.quat_identity()), radius=0.25)
    h = 1.0 / n
    b.add_cloth_grid(
        pos=wp.vec3(-0.5, -0.5, 0.56),
        rot=wp.quat_identity(),
        vel=wp.vec3(0.0, 0.0, 0.0),
        dim_x=n,
        dim_y=n,
        cell_x=h,
        cell_y=h,
        mass=RHO * T / (n + 1) ** 2,  # per particle
        tri_ke=MU_T,
        tri_ka=LAM_T,
        tri_kd=0.0,
        edge_ke=2
        * D
        / h,  # Newton's hinge k L (theta - theta0)^2 / 2; the discrete shell's D |e|^2 / (A1 + A2)
        edge_kd=0.0,
        particle_radius=2.0e-3,
    )
    b.color(include_bending=True)
    model = b.finalize(device="cpu")
    model.soft_contact_ke = 1.0e4
    model.soft_contact_kd = 1.0e-2
    model.soft_contact_mu = 0.3
    solver = newton.solvers.SolverVBD(
        model=model,
        iterations=iterations,
        particle_enable_self_contact=True,
        particle_self_contact_margin=2.0e-3,
        particle_self_contact_gap=2.0e-3,
    )
    s0, s1, ctl = model.state(), model.state(), model.control()
    pipe = newton.CollisionPipeline(model)
    contacts = pipe.contacts()
    dt = 1.0 / 60.0 / substeps
    nsub = int(round(duration / dt))

    def step(k):
        nonlocal s0, s1
        for _ in range(k):
            s0.clear_forces()
            pipe.collide(s0, contacts)
            solver.step(s0, s1, ctl, contacts, dt)
            s0, s1 = s1, s0

    t0 = time.perf_counter()
    step(1)  # compiles (Warp's kernel cache may hold it from an earlier run)
    wp.synchronize()
    first = time.perf_counter() - t0
    w0 = time.perf_counter()
    step(nsub - 1)
    wp.synchronize()
    wall = time.perf_counter() - w0
    q = s0.particle_q.numpy()
    np.save(out + "_x.npy", q)
    np.save(out + "_tris.npy", model.tri_indices.numpy())
    res = {
        "code": f"Newton {newton.__version__} VBD (Warp {wp.__version__}, CPU)",
        "vertices": int(model.particle_count),
        "dt": dt,
        "iterations": iterations,
        "substeps": nsub - 1,
        "stepping_s": wall,
        "sim_s": (nsub - 1) * dt,
        "first_substep_s": first,
        "z_mean": float(q[:, 2].mean()),
        "finite": bool(np.isfinite(q).all()),
    }
    Path(out + ".json").write_text(json.dumps(res))


def run_simcli(n: int, duration: float, dt: float, sets: list[str]) -> dict:
    import ipctk

    from benchmarks.cloth_bench import FEM, SCENE
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections
    from simcli.solvers.fem.cloth.solver import ClothSolver

    ipctk.set_num_threads(1)
    steps = int(round(duration / dt))
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.yaml"
        p.write_text(SCENE.format(substeps=1, duration=duration, material=FEM, n=n))
        ld = load_scene(p, sets)
    s = ClothSolver(ld.scene, [], scene_dir=None)
    s.build()
    w0 = time.perf_counter()
    for _ in range(steps):
        s.substep(dt)
    wall = time.perf_counter() - w0
    st = s.info()
    return {
        # the factorisation solvers.fem.linear_solver chose (auto: CHOLMOD where the cholmod extra is there)
        "code": "simcli FEM.Cloth ("
        + st["factorization"].split()[0]
        + ")"
        + (" " + " ".join(sets) if sets else ""),
        "vertices": s.n,
        "dt": dt,
        "substeps": steps,
        "stepping_s": wall,
        "sim_s": steps * dt,
        "newton_per_substep": st["newton_per_substep"],
        "contacts_per_substep": st["contacts_per_substep"],
        "z_mean": float(s.x[:, 2].mean()),
        "intersections": len(edge_triangle_intersections(s.x, s.tris)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", type=int, default=32, help="sheet cells per side")
    ap.add_argument("--duration", type=float, default=0.4, help="simulated time [s]")
    ap.add_argument("--iterations", default="10,20,40,80", help="Newton VBD sweeps per substep, a list")
    ap.add_argument("--substeps", type=int, default=10, help="Newton: substeps per 1/60 s")
    ap.add_argument("--newton-python", default=str(Path.home() / "newton-venv/bin/python"))
    ap.add_argument(
        "--simcli-set", action="append", default=[], metavar="KEY=VALUE", help="extra simcli runs"
    )
    ap.add_argument("--no-reference", action="store_true", help="skip simcli at Newton's step")
    ap.add_argument("--out", default=None, help="write the markdown table here")
    ap.add_argument("--worker", nargs=3, metavar=("CELLS", "ITERATIONS", "OUT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        run_newton(int(a.worker[0]), a.duration, a.substeps, int(a.worker[1]), a.worker[2])
        return
    import numpy as np

    from benchmarks.bench import machine
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections

    rows = []
    tmp = tempfile.mkdtemp()
    for it in [int(k) for k in a.iterations.split(",")]:
        out = os.path.join(tmp, f"vbd{it}")
        r = subprocess.run(
            [a.newton_python, __file__, "--duration", str(a.duration), "--substeps", str(a.substeps)]
            + ["--worker", str(a.cells), str(it), out],
            capture_output=True,
            text=True,
        )
        if r.returncode:
            raise SystemExit(f"Newton failed ({r.returncode}): {r.stderr[-3000:]}")
        res = json.loads(Path(out + ".json").read_text())
        q, tris = np.load(out + "_x.npy"), np.load(out + "_tris.npy")
        res["intersections"] = len(edge_triangle_intersections(q.astype(float), tris))
        print(json.dumps(res), flush=True)
        rows.append(res)
    sim = [run_simcli(a.cells, a.duration, 0.01, [])]
    print(json.dumps(sim[-1]), flush=True)
    for kv in a.simcli_set:
        sim.append(run_simcli(a.cells, a.duration, 0.01, [kv]))
        print(json.dumps(sim[-1]), flush=True)
    ref = None
    if not a.no_reference:
        ref = run_simcli(a.cells, a.duration, 1.0 / 60.0 / a.substeps, [])
        print(json.dumps(ref), flush=True)
    vbd_ref = rows[-1]["z_mean"]
    cmd = (
        f"PYTHONPATH=. python benchmarks/cloth_vs_newton.py --cells {a.cells} --duration {a.duration} "
        f"--iterations {a.iterations} --out docs/PERFORMANCE_CLOTH.md"
    )
    lines = [
        "## FEM.Cloth beside Newton's VBD",
        "",
        f"Regenerate with `{cmd}` (measured {time.strftime('%Y-%m-%d')} on {machine()}; one thread for each "
        f"code, one run each, in sequence). The sheet of benchmarks/cloth_bench.py ({a.cells} x {a.cells} "
        f"cells) dropped onto a sphere, {a.duration} s simulated. Error: the sheet's mean height at the end "
        "against the code's own converged limit (Newton: its most iterations; simcli: FEM.Cloth at Newton's "
        "step, last row).",
        "",
        "| code | vertices | step [ms] | VBD sweeps or Newton steps per substep | substeps/s | simulated s "
        "per wall s | mean height [m] | error vs own limit [mm] | intersections at the end |",
        "|---|---|---|---|---|---|---|---|---|",
    ]

    def row(r, per, err):
        speed = f"{r['substeps'] / r['stepping_s']:.3g} | {r['sim_s'] / r['stepping_s']:.3g}"
        head = f"| {r['code']} | {r['vertices']} | {r['dt'] * 1e3:.3g} | {per:.3g}"
        return f"{head} | {speed} | {r['z_mean']:.5f} | {err} | {r['intersections']} |"

    for r in rows:
        lines.append(row(r, r["iterations"], f"{(r['z_mean'] - vbd_ref) * 1e3:+.2f}"))
    for r in sim + ([ref] if ref else []):
        err = f"{(r['z_mean'] - ref['z_mean']) * 1e3:+.2f}" if ref else "-"
        lines.append(row(r, r["newton_per_substep"], err))
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        p = Path(a.out)
        old = p.read_text() if p.exists() else "# FEM.Cloth performance\n\n"
        head = f"## FEM.Cloth beside Newton's VBD ({a.cells} x {a.cells} cells)"
        text = text.replace("## FEM.Cloth beside Newton's VBD", head, 1)
        if head in old:  # replace this size's section where it stands, keep the others
            pre, rest = old.split(head, 1)
            nxt = rest.find("\n## ")
            p.write_text(pre + text + (rest[nxt:] if nxt >= 0 else ""))
        else:
            p.write_text(old.rstrip() + "\n\n" + text)


if __name__ == "__main__":
    main()
