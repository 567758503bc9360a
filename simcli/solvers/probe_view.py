"""What a particle family shows the probes' device path (simcli/probes/device.py): its Taichi fields by slot,
so that a probe sample reads only the particles near its probes instead of copying whole fields to the
host (``Solver.entity_arrays``).

The rows of an entity's ``entity_arrays`` are the slots whose ``key`` lies in the entity's range, ordered by
``key`` (SPH: the particle's id, its slot being re-sorted every substep; MPM with emitters or sinks: its id;
MPM otherwise: the slot itself, ``key`` None). A family returns a :class:`ProbeView` from
``Solver.probe_view()``; None (the default) keeps its probes on the host path.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable


@dataclass
class ProbeView:
    x: Any  # ti.Vector.field (n,) of dim: positions by slot
    key: Any  # ti.field i32 (n,): the slot's row in output order, or None: the slot itself
    n_live: Callable[[], int]  # live slots [0, n_live()) now (host-side count, no sync)
    ranges: dict[str, tuple[int, int]]  # entity name -> [lo, hi) of its keys
    field: Callable[[str], Any]  # output field name -> ti field by slot (scalar or vector); KeyError if none
    dtype: Any  # numpy dtype of the float fields as entity_arrays returns them
    # fields computed from the state only where asked (MPM's J, pressure, ...): derive is a ti.func(p) that
    # computes them at slot p (into the fields ``field`` gives for them) before they are read
    derived: tuple[str, ...] = ()
    derive: Any = None
