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
    b = int(estimate_bytes(nv, nt, scene.solvers.fem.integrator, scene.sim.precision) * FEM_HOST_FACTOR)
    return Part(
        "FEM",
        f"{nv:,} vertices, {nt:,} tetrahedra",
        b,
        ("solvers", "fem", "resolution"),
        "lower solvers.fem.resolution (Box morphs) or raise solvers.fem.max_volume (other shapes)",
        out_bytes=nv * out_floats(scene, DEFAULT_FIELDS, 3) * 4,  # float32 at either precision
        state_bytes=nv * 4 * fp_factor(scene) * 6,  # x, v
        static_out_bytes=nt * 4 * 8,
    )
