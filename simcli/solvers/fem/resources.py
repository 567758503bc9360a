"""FEM's memory estimate from the scene alone (no Taichi, no mesh built): its Part of
``simcli.scene.resources``; the per-element bytes are ``simcli.solvers.fem.checks.estimate_bytes``."""

from __future__ import annotations

from simcli.geometry.tetmesh import estimate_counts
from simcli.scene.estimate import MIB, Part, fp_factor, out_floats
from simcli.solvers.fem.checks import estimate_bytes

# Peak RSS of `simcli run` with a tiny FEM scene (simcli.scene.resources: the baseline)
BASELINE = 190 * MIB
FALLBACK = (("solvers", "fem", "resolution"), "lower solvers.fem.resolution")
DEFAULT_FIELDS = ["position", "velocity", "displacement", "von_mises", "J"]


def baseline(scene) -> int:
    return BASELINE


FEM_HOST_FACTOR = 1.17


def estimate(scene, scene_dir, lo, hi) -> Part | None:
    nv = nt = 0
    for e in scene.entities:
        if e.family == "FEM":
            v, t = estimate_counts(e, scene.solvers.fem, scene_dir)
            nv, nt = nv + v, nt + t
    what = f"{nv:,} vertices, {nt:,} tetrahedra"
    if getattr(scene.solvers.fem, "element", "tet4") == "tet10":
        # quadratic tetrahedra: a node per edge (Kuhn-split boxes: 7 edges per 6 tets plus the
        # boundary's, 1.44 per tet at 3,840 tets), 4 Gauss points per element, each with 10-node slots
        # (priced as 2 linear tets; an estimate, not measured)
        nv = nv + (3 * nt) // 2
        what = f"{nv:,} nodes, {nt:,} quadratic tetrahedra"
        nk = 8 * nt
    else:
        nk = nt
    b = int(estimate_bytes(nv, nk, scene.solvers.fem.integrator, scene.sim.precision) * FEM_HOST_FACTOR)
    return Part(
        "FEM",
        what,
        b,
        ("solvers", "fem", "resolution"),
        "lower solvers.fem.resolution (Box morphs) or raise solvers.fem.max_volume (other shapes)",
        out_bytes=nv * out_floats(scene, DEFAULT_FIELDS, 3) * 4,  # float32 at either precision
        state_bytes=nv * 4 * fp_factor(scene) * 6,  # x, v
        static_out_bytes=nt * 4 * 8,
    )
