"""FEM.Cloth: cost per substep and crossings of a sheet draped over a `type: Cylinder` collider's top rim and
over a `type: Sphere` collider (issue 21). Since 2026-11-27 the Cylinder is a circumscribed prism in the IPC
contact (simcli.solvers.fem.cloth.mesh_obstacles); before, an exact signed distance per cloth vertex, which
let its rim through the sheet's edges and triangles. The Sphere is still such a signed distance (its faces
dip in: docs/FEM.md, "Remaining gaps"). Run it with PYTHONPATH at another checkout to measure that one (the
script needs nothing of this one).

    PYTHONPATH=. python benchmarks/cloth_round_collider_cost.py [--size 0.4] [--res 16] [--substeps 30]
        [--repeats 2]

A --size m FEM.Cloth square (--res cells per side, contact_distance 2 mm) dropped from 1 cm above (a) an
upright Cylinder (radius 0.1 m, top at z = 0.25) and (b) a Sphere (radius 0.1 m, top at z = 0.3); each
variant's ClothSolver (host numpy/scipy/ipctk, float64) runs --substeps substeps of 10 ms, the variants in
turn --repeats times (interleaved, so a load change on a shared machine hits them alike). Reported: the
median CPU time of the process per substep, Newton iterations and contact pairs per substep, the CCD time,
the obstacle triangles, the lowest point at the end, and the largest number of crossings over the substeps
against the exact shape, checked independently of the solver's triangles: for the Cylinder, segment-triangle
crossings with a 256-sided inscribed prism (within 7.5 um of it) plus vertices inside the exact cylinder; for
the Sphere, cloth triangles closer to its centre than the radius (exact), with the deepest reach [mm]."""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

SCENE = """\
version: 1
sim: {{dim: 3, dt: 1.0e-2, substeps: 1, duration: 1.0}}
domain: {{lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 0.6]}}
colliders:
  - {{name: body, {col}, friction: 0.3}}
solvers:
  fem: {{contact_distance: 2.0e-3}}
entities:
  - name: c
    material: {{type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 200, thickness: 1.0e-3, friction: 0.2}}
    morph: {{type: Rectangle, center: [0.0, 0.0, {z}], size: [{size}, {size}], resolution: {res}}}
"""

VARIANTS = {
    "Cylinder (rim drape)": ("type: Cylinder, center: [0, 0, 0.15], radius: 0.1, height: 0.2, axis: z", 0.26),
    "Sphere (drape)": ("type: Sphere, center: [0, 0, 0.2], radius: 0.1", 0.31),
}


def _prism(n=256, r=0.1, h=0.2, c=(0, 0, 0.15)):
    import numpy as np

    a = 2 * np.pi * np.arange(n) / n
    ring = np.stack([r * np.cos(a), r * np.sin(a), np.zeros(n)], 1)
    V = np.concatenate([ring - [0, 0, h / 2], ring + [0, 0, h / 2], [[0, 0, -h / 2], [0, 0, h / 2]]]) + c
    i = np.arange(n)
    j = (i + 1) % n
    T = np.concatenate(
        [
            np.stack([i, j, n + j], 1),
            np.stack([i, n + j, n + i], 1),
            np.stack([np.full(n, 2 * n), j, i], 1),
            np.stack([np.full(n, 2 * n + 1), n + i, n + j], 1),
        ]
    )
    return V, T


def _crossings(name, x, tris) -> tuple[int, float]:
    import numpy as np

    from simcli.collider_mesh import point_triangle_distance
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections

    if name.startswith("Cylinder"):
        V, T = _prism()
        n = len(x)
        hits = edge_triangle_intersections(np.concatenate([x, V]), np.concatenate([tris, T + n]), cell=0.05)
        k = sum(1 for h in hits if (h[0][0] < n) == (h[1] >= len(tris)))
        y = x - [0, 0, 0.15]
        k += int(((np.hypot(y[:, 0], y[:, 1]) < 0.1) & (np.abs(y[:, 2]) < 0.1)).sum())
        return k, 0.0
    c = np.array([[0, 0, 0.2]])
    d = point_triangle_distance(np.repeat(c, len(tris), 0), x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]])
    return int((d < 0.1).sum()), max(0.0, 1e3 * (0.1 - float(d.min())))


def run(name: str, size: float, res: int, n: int, tmp: Path) -> dict:
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.cloth.solver import ClothSolver

    col, z = VARIANTS[name]
    p = tmp / "scene.yaml"
    p.write_text(SCENE.format(col=col, size=size, res=res, z=z))
    ld = load_scene(p)
    s = ClothSolver(ld.scene, [], scene_dir=ld.scene_dir)
    s.build()
    cpu, worst, depth = 0.0, 0, 0.0
    for _ in range(n):
        c0 = time.process_time()
        s.substep(0.01)
        cpu += time.process_time() - c0
        k, dep = _crossings(name, s.x, s.tris)
        worst, depth = max(worst, k), max(depth, dep)
    i = s.info()
    return dict(
        cpu=cpu / n,
        newton=i["newton_per_substep"],
        contacts=i["contacts_per_substep"],
        ccd=i["ccd_s"] / n,
        tris=len(getattr(getattr(s, "mobst", None), "T", ())),
        zmin=float(s.x[:, 2].min()),
        crossings=worst,
        depth_mm=depth,
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=float, default=0.4)
    ap.add_argument("--res", type=int, default=16)
    ap.add_argument("--substeps", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    out: dict[str, list[dict]] = {k: [] for k in VARIANTS}
    with tempfile.TemporaryDirectory() as d:
        for _ in range(a.repeats):
            for name in VARIANTS:
                out[name].append(run(name, a.size, a.res, a.substeps, Path(d)))
    print(
        f"FEM.Cloth {a.size} m sheet, {(a.res + 1) ** 2} vertices, {a.substeps} substeps of 10 ms, median of "
        f"{a.repeats} (CPU s per substep)"
    )
    print(
        f"{'variant':22s} {'CPU s/substep':>13s} {'Newton/substep':>14s} {'contacts':>9s} {'CCD s':>7s} "
        f"{'obst tris':>9s} {'zmin':>7s} {'crossings':>9s} {'depth mm':>8s}"
    )
    for name, rs in out.items():
        m = {k: statistics.median(r[k] for r in rs) for k in rs[0]}
        print(
            f"{name:22s} {m['cpu']:13.3f} {m['newton']:14.2f} {m['contacts']:9.1f} {m['ccd']:7.3f} "
            f"{m['tris']:9.0f} {m['zmin']:7.4f} {m['crossings']:9.0f} {m['depth_mm']:8.3f}"
        )


if __name__ == "__main__":
    main()
