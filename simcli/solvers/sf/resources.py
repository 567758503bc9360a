"""SF's memory estimate from the scene alone (no Taichi): its Part of ``simcli.scene.resources``; the
grid's bytes are ``simcli.solvers.sf.config.estimate_bytes``."""

from __future__ import annotations

import math

from simcli.scene.estimate import MIB, Part, fp_factor, out_floats
from simcli.solvers.sf.config import estimate_bytes

# Peak RSS of `simcli run` with a tiny SF scene (simcli.scene.resources: the baseline)
BASELINE = 320 * MIB
FALLBACK = (("solvers", "sf", "resolution"), "lower solvers.sf.resolution")
DEFAULT_FIELDS = ["velocity", "pressure", "density", "temperature", "divergence"]


def baseline(scene) -> int:
    return BASELINE


SF_HOST_FACTOR = 1.38


def estimate(scene, scene_dir, lo, hi) -> Part | None:
    n, _ = scene.solvers.sf.cells(lo, hi)
    cells = math.prod(n)
    mat = next((e.material for e in scene.entities if e.family == "SF"), None)
    # estimate_bytes includes 256 MiB of Taichi runtime, counted here in the baseline
    b = int((estimate_bytes(scene.solvers.sf, mat, n, scene.sim.precision) - (256 << 20)) * SF_HOST_FACTOR)
    return Part(
        "SF",
        f"{'x'.join(map(str, n))} = {cells:,} grid cells",
        b,
        ("solvers", "sf", "resolution"),
        "lower solvers.sf.resolution",
        # a grid family writes no positions; float32 at either precision
        out_bytes=cells * out_floats(scene, DEFAULT_FIELDS, len(n), with_position=False) * 4,
        state_bytes=cells
        * 4
        * fp_factor(scene)
        * (len(n) + 3),  # face velocities, smoke and temperature, pressure
    )
