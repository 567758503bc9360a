"""The output fields each family writes (``output.fields``), Taichi-free, so that ``simcli validate`` refuses
a field an entity cannot write with its location, as ``run`` would after building its solvers
(runner._entity_meta checks the solvers' ``output_fields()``; the solvers' ``OUTPUT_FIELDS`` are these tuples,
and tests/unit/test_output_fields.py keeps their ``output_fields()`` in step)."""

from __future__ import annotations

from typing import Any, Callable

FIELDS: dict[str, tuple[str, ...]] = {
    "MPM": ("position", "velocity", "J", "stress", "pressure", "Jp", "elastic_energy", "mass", "material_id"),
    "SPH": ("position", "velocity", "density", "pressure", "material_id"),
    "PBD": ("position", "velocity", "reaction", "displacement", "density"),
    "FEM": (
        "position",
        "velocity",
        "displacement",
        "von_mises",
        "J",
        "von_mises_nodal",
        "J_nodal",
        "mass",
        "elastic_energy",
    ),
    "FEMCloth": ("position", "velocity", "displacement", "mass", "strain", "stress"),
    "SF": ("velocity", "pressure", "density", "temperature", "divergence", "vorticity", "solid"),
}


def check_output_fields(s: Any, err: Callable) -> None:
    """An explicit ``output.fields`` list: every entity (emitters included) must write each field."""
    fields = s.output.fields
    if fields == "default":
        return
    for e in list(s.entities) + list(s.emitters):
        avail = FIELDS.get(e.family)
        if avail is None:
            continue
        unknown = [f for f in fields if f not in avail]
        if unknown:
            err(
                ("output", "fields"),
                f"unknown field(s) {', '.join(unknown)} for entity '{e.name}' ({e.family}; available: "
                f"{', '.join(avail)}): remove them, or write them only where every entity has them "
                "(output.fields applies to every entity)",
            )
