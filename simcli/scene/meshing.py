"""Tetrahedral meshing parameters (no Taichi, no numpy): what ``simcli.geometry.tetmesh.mesh_for_entity``
reads, with FEM's defaults. ``FEMOptions`` carries the same fields (and takes its default quality bound
from here); PBD.Elastic solids are meshed with a :class:`Meshing` at ``solvers.pbd.tet_resolution``, so
the PBD family needs nothing of the FEM family's."""

from __future__ import annotations

from dataclasses import dataclass

MIN_DIHEDRAL = 10.0  # [deg] default quality bound of the tetrahedraliser (solvers.fem.min_dihedral's default)


@dataclass(frozen=True)
class Meshing:
    """The parameters ``mesh_for_entity`` reads, with FEM's defaults (``FEMOptions`` has the same fields
    and passes itself)."""

    resolution: float  # cells per metre (Box morphs)
    max_volume: float | None = None  # largest tetrahedron [m^3] (default resolution^-3 / 6)
    min_dihedral: float = MIN_DIHEDRAL
    surface_resolution: float | None = None  # surface triangles' edges per metre (default resolution)
