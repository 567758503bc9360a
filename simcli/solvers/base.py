"""The interface every solver family implements, and the data it exchanges.

No Taichi import here (only inside ``Solver.sync``): the config side (validate, schema) and the
writers must be able to import this module without starting Taichi. ``Body``, the sampled initial
state the solvers consume, lives in ``simcli.geometry.body`` (it is produced by
``simcli.geometry.sampling``) and is re-exported here as part of the solver interface.

Lifecycle (see docs/ARCHITECTURE.md):

* ``__init__(scene, bodies)``: keeps the config and the numpy initial state; no
  Taichi allocation.
* ``build()``: allocates every field once and uploads the bodies.
* ``substep(dt)``: one substep; never allocates, never syncs to the host.
* ``frame_check()``: once per output frame, one small reduction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from simcli.geometry.body import Body

__all__ = [
    "RUNAWAY_CFL",
    "Body",
    "FrameStats",
    "Solver",
    "frame_stats_per_body",
    "initial_positions",
    "upload_state_array",
]

if TYPE_CHECKING:  # pragma: no cover
    from simcli.scene.models import Scene

# A substep whose CFL number (max speed * substep / length_scale()) exceeds this is a blow-up: MPM's
# transfers assume particles move less than a cell per substep. The runner's runaway guard applies it;
# Solver.runaway_cfl() returns it unless a family has a limit of its own (SF: solvers.sf.max_cfl).
RUNAWAY_CFL = 2.0


@dataclass
class FrameStats:
    """Health of one entity at a frame boundary."""

    finite: bool  # every position and velocity component is finite
    max_speed: float  # largest particle speed [m/s] (inf/nan when not finite)
    n_bad: int  # number of particles with a non-finite position or velocity


def frame_stats_per_body(names, speed, bad) -> dict[str, FrameStats]:
    """FrameStats of each named body from its largest speed ``speed[k]`` and its count of non-finite
    particles ``bad[k]`` (k: the name's position); a body with any bad particle reports speed inf."""
    out = {}
    for k, name in enumerate(names):
        nbad = int(bad[k])
        out[name] = FrameStats(
            finite=nbad == 0, max_speed=float(speed[k]) if nbad == 0 else float("inf"), n_bad=nbad
        )
    return out


def initial_positions(bodies, lo: np.ndarray, hi: np.ndarray, tol: float, solver: str) -> np.ndarray:
    """Every body's initial positions stacked, (n, dim), after checking that they are finite and inside
    the domain [lo, hi] up to ``tol`` (ValueError naming ``solver`` or the entity if not); not clipped."""
    xs = np.concatenate([b.x for b in bodies])
    if not np.all(np.isfinite(xs)):
        raise ValueError(f"{solver}: initial particle positions are not finite")
    for b in bodies:
        if b.n and (np.any(b.x < lo - tol) or np.any(b.x > hi + tol)):
            raise ValueError(f"entity {b.name!r}: particles outside the domain {lo.tolist()} - {hi.tolist()}")
    return xs


def upload_state_array(fld, state: dict, key: str, shape: tuple, dtype, family: str) -> None:
    """``fld.from_numpy(state[key])`` as ``dtype``, after checking that its shape is ``shape`` (set_state)."""
    arr = np.ascontiguousarray(state[key], dtype=dtype)
    if arr.shape != shape:
        raise ValueError(f"{family} state {key!r}: shape {arr.shape}, expected {shape}")
    fld.from_numpy(arr)


class Solver:
    """Base class of a solver family. Subclasses implement every method below."""

    family: ClassVar[str] = ""
    # emitters and sinks (simcli.solvers.sources.ActiveSet: a changing particle count) of MPM and SPH;
    # None in every other solver and scene (SF's own `sources` are its jets, a different thing)
    active_set: Any = None
    # per-cell output fields among output_fields() (written per tet/triangle, not per vertex)
    cell_fields: ClassVar[tuple[str, ...]] = ()
    # simcli.colliders.ColliderPoses of this family's moving and named colliders (None: it has none);
    # read through collider_poses()
    poses: Any = None

    def __init__(self, scene: Scene, bodies: list[Body], scene_dir: Any = None) -> None:
        self.scene = scene
        self.bodies = list(bodies)
        self.scene_dir = scene_dir  # files named in the scene (meshes, CSV motions) resolve against it
        self.warnings: list[str] = []  # what the solver changed of the scene as given (run.json, stderr)

    def build(self) -> None:
        """Allocate fields once and upload the initial state."""
        raise NotImplementedError

    def substep(self, dt: float) -> None:
        """Advance by ``dt`` seconds; no allocation, no host sync."""
        raise NotImplementedError

    # The coupling phase between families (simcli/coupling/, docs/COUPLING.md): a coupled scene runs
    # pre_couple -> the coupler -> post_couple instead of substep. A family that exposes no state to the
    # coupler keeps these defaults (its whole substep before the coupling phase); MPM and SPH split theirs.
    def pre_couple(self, dt: float) -> None:
        """The substep up to the state the coupling phase reads and edits (default: all of it)."""
        self.substep(dt)

    def post_couple(self, dt: float) -> None:
        """The rest of the substep after the coupling phase (default: nothing)."""

    def frame_check(self) -> dict[str, FrameStats]:
        """Per entity: all finite? largest speed? (one small reduction)."""
        raise NotImplementedError

    def entity_arrays(self, name: str, fields: list[str]) -> dict[str, np.ndarray]:
        """Arrays of one entity's particles for the given output field names."""
        raise NotImplementedError

    def probe_view(self):
        """A :class:`simcli.solvers.probe_view.ProbeView` of the particle fields, so that probes read only
        the particles near them on the device; None (default): probes read :meth:`entity_arrays`."""
        return None

    def get_state(self) -> dict[str, np.ndarray]:
        """Everything needed to restart bit-for-bit."""
        raise NotImplementedError

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        raise NotImplementedError

    def stable_dt(self, horizon: float = 0.0) -> float:
        """Largest stable substep for the current state [s], to be kept for the next ``horizon`` seconds
        (simcli.substeps.SubstepPolicy.horizon: a frame, or the last substep when the substep is chosen
        before each one): a family whose limit shrinks as gravity speeds it up bounds it over that span."""
        raise NotImplementedError

    def counts(self) -> dict[str, int]:
        """Sizes worth reporting: particles, cells, ..."""
        raise NotImplementedError

    def output_fields(self) -> dict[str, tuple[int, str]]:
        """Per-entity output fields this family can write: name -> (components, unit)."""
        raise NotImplementedError

    def entity_kind(self, name: str) -> str:
        """How an entity is written: particles | tets | triangles | lines | grid."""
        return "particles"

    def steady(self) -> dict | None:
        """Called after each written frame: a dict describing why the state has stopped changing by
        the family's own criterion (the runner then ends the run there), or None to go on."""
        return None

    def entity_cells(self, name: str):
        """Static topology (n_cells, nodes per cell) of a mesh entity, or None."""
        return None

    def default_fields(self, name: str) -> list[str]:
        """What ``output.fields: default`` writes for this entity."""
        return ["position", "velocity"]

    def entity_grid(self, name: str):
        """For a grid entity: (shape in x, y[, z] order, origin, spacing); None otherwise."""
        return None

    def entity_size(self, name: str) -> int:
        """Rows of the entity's per-point arrays (particles, vertices)."""
        b = next(b for b in self.bodies if b.name == name)
        return b.n

    def owns(self, name: str) -> bool:
        """Whether entity ``name`` is simulated by this solver."""
        return any(b.name == name for b in self.bodies)

    def sync(self) -> None:
        """Wait for queued kernels (timing and signal handling happen on step boundaries)."""
        import taichi as ti

        ti.sync()

    def length_scale(self) -> float:
        """Resolution length [m] the runaway guard measures CFL numbers against (grid cell,
        particle spacing)."""
        raise NotImplementedError

    def splits_substep(self) -> bool:
        """Whether this family must stay under its own stable_dt() inside the common substep (the runner's
        substep policy then gives it SubstepPolicy.split(dt, stable_dt()) equal substeps of its own, in
        scenes without a coupling phase); MPM with hardening under substeps: auto."""
        return False

    def runaway_cfl(self) -> float:
        """The runaway guard's limit: a substep whose CFL number (max speed x substep / length_scale())
        exceeds it is a blow-up. Particle methods cannot take more than about two cells per substep."""
        return RUNAWAY_CFL

    def runaway_advice(self, name: str, sim: Any) -> str:
        """What to change when entity ``name`` ran away or went non-finite (the runner adds the substep
        count that would keep the CFL number below 0.5 when substeps are fixed)."""
        subs = sim.substeps if sim.substeps != "auto" else "auto"
        return (
            f"lower sim.dt (now {sim.dt:g} s), raise sim.substeps (now {subs}) or use substeps: "
            f"auto, or lower the stiffness E of '{name}'"
        )

    def collider_loads(self) -> dict[str, np.ndarray]:
        """Impulse on each named collider since the last call, name -> (dim + 3,) [N s, N m s]; a
        family without named colliders returns {}."""
        return {}

    def collider_poses(self) -> Any:
        """The ColliderPoses the family's kernels read its moving colliders from (rigid bodies write
        their pose there and read their load back), or None."""
        return self.poses

    def info(self) -> dict[str, Any]:
        """Optional extra facts for run.json (design choices, sizes)."""
        return {}
