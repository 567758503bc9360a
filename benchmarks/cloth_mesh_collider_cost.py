"""FEM.Cloth: cost per substep against a Mesh collider beside the same scene with the equivalent Box collider
(issue 21; both are in the IPC contact as triangles since 2026-11-27: before, the Box was an exact signed
distance per cloth vertex, and the crossings below are what that let through).

    PYTHONPATH=. python benchmarks/cloth_mesh_collider_cost.py [--size 0.4] [--res 16] [--substeps 30]
        [--repeats 2] [--crossings]

A --size m FEM.Cloth square (--res cells per side) dropped from 1 cm above the top of a 0.2 m box, which is in
turn (a) a still Box collider, (b) a still Mesh collider (configs/meshes/cube.obj, 12 triangles, the same
box), (c) the Box turning at 1 rev/s about the vertical axis through its centre, (d) the Mesh turning alike.
Each variant's ClothSolver (host numpy/scipy/ipctk, float64) runs --substeps substeps of 10 ms from the
same start; the variants run in turn --repeats times (interleaved, so a load change on a shared machine hits
them alike). Reported: the median CPU time of the process per substep, Newton iterations and contact pairs
per substep (the Box counts vertex-box pairs, the Mesh ipctk's point-triangle, edge-edge, ... pairs), the CCD
time, the cloth's lowest point at the end, and (--crossings) the largest number of segment-triangle
crossings of the cloth with the box's 12 triangles at its pose over the substeps (the independent check of
the tests). A sheet larger than the top (0.4 m) drapes over the box's edges: the old Box primitive kept the
cloth's vertices out of it, not its edges (they cut the box's edges), the Mesh keeps both out; a sheet
smaller than the top (0.16 m) rests flat on it. Box and Mesh now run the same trajectory."""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TURN = "motion: {angular_velocity: [0, 0, 6.283185307179586]}"
CUBE = (ROOT / "configs" / "meshes" / "cube.obj").as_posix()
VARIANTS = {
    "still Box": "{type: Box, lower: [-0.1, -0.1, 0.1], upper: [0.1, 0.1, 0.3], friction: 0.3}",
    "still Mesh (cube, 12 triangles)": (
        f"{{type: Mesh, file: {CUBE}, scale: 0.2, translate: [0, 0, 0.2], friction: 0.3}}"
    ),
    "Box turning 1 rev/s": (
        f"{{type: Box, lower: [-0.1, -0.1, 0.1], upper: [0.1, 0.1, 0.3], friction: 0.3, {TURN}}}"
    ),
    "Mesh turning 1 rev/s": (
        f"{{type: Mesh, file: {CUBE}, scale: 0.2, translate: [0, 0, 0.2], friction: 0.3, {TURN}}}"
    ),
}
SCENE = """\
version: 1
sim: {{dim: 3, dt: 1.0e-2, substeps: 1, duration: 1.0}}
domain: {{lower: [-1, -1, 0], upper: [1, 1, 1]}}
colliders:
  - {col}
solvers:
  fem: {{contact_distance: 2.0e-3}}
entities:
  - name: c
    material: {{type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 200, thickness: 1.0e-3, friction: 0.2}}
    morph: {{type: Rectangle, center: [0.01, 0.02, 0.31], size: [{size}, {size}], resolution: {res}}}
"""


def run(col: str, size: float, res: int, n: int, tmp: Path, crossings: bool) -> dict:
    import numpy as np

    from simcli.geometry.mesh import read_surface
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections
    from simcli.solvers.fem.cloth.solver import ClothSolver

    p = tmp / "scene.yaml"
    p.write_text(SCENE.format(col=col, size=size, res=res))
    ld = load_scene(p)
    s = ClothSolver(ld.scene, [], scene_dir=ld.scene_dir)
    s.build()
    Vc, Tc = read_surface(CUBE)
    Vw = np.asarray(Vc) * 0.2 + [0, 0, 0.2]
    cpu, worst = 0.0, 0
    for _ in range(n):
        c0 = time.process_time()
        s.substep(0.01)
        cpu += time.process_time() - c0
        if crossings:
            ms = [m for m in [*s.obst.motions, *s.obst.mesh_motions] if m is not None]
            V = ms[0].pose(s.tau).to_world(Vw) if ms else Vw
            X = np.concatenate([s.x, V])
            worst = max(worst, len(edge_triangle_intersections(X, np.concatenate([s.tris, Tc + s.n]))))
    cpu /= n
    i = s.info()
    return dict(
        cpu=cpu,
        newton=i["newton_per_substep"],
        contacts=i["contacts_per_substep"],
        ccd=i["ccd_s"] / n,
        zmin=float(s.x[:, 2].min()),
        crossings=worst,
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=float, default=0.4)
    ap.add_argument("--res", type=int, default=16)
    ap.add_argument("--crossings", action="store_true")
    ap.add_argument("--substeps", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    out: dict[str, list[dict]] = {k: [] for k in VARIANTS}
    with tempfile.TemporaryDirectory() as d:
        for _ in range(a.repeats):
            for name, col in VARIANTS.items():
                out[name].append(run(col, a.size, a.res, a.substeps, Path(d), a.crossings))
    n = (a.res + 1) ** 2
    print(
        f"FEM.Cloth {a.size} m sheet, {n} vertices, {a.substeps} substeps of 10 ms, median of {a.repeats} "
        "(CPU s per substep)"
    )
    print(
        f"{'variant':34s} {'CPU s/substep':>13s} {'Newton/substep':>14s} {'contacts':>9s} "
        f"{'CCD s':>7s} {'zmin':>7s} {'crossings':>9s}"
    )
    for name, rs in out.items():
        m = {k: statistics.median(r[k] for r in rs) for k in rs[0]}
        print(
            f"{name:34s} {m['cpu']:13.3f} {m['newton']:14.2f} {m['contacts']:9.1f} {m['ccd']:7.3f} "
            f"{m['zmin']:7.4f} {m['crossings']:9.0f}"
        )


if __name__ == "__main__":
    main()
