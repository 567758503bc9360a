"""Moved: the tetrahedral mesher is ``simcli.geometry.tetmesh`` (FEM's elements and PBD.Elastic's soft
bodies share it), FEM's scene checks and memory estimate are ``simcli.solvers.fem.checks``.

TODO(issue 17): this module only re-exports them for the importers not yet moved (``scene/checks.py``
and branches in flight); import from the two modules above and delete it.
"""

from __future__ import annotations

from simcli.geometry.tetmesh import (  # noqa: F401
    DEGENERATE_REL,
    TetMesh,
    boundary_faces,
    box_tets,
    estimate_counts,
    mesh_for_entity,
    orient,
    read_tets,
    signed_volumes,
    tetrahedralise,
    validate,
)
from simcli.solvers.fem.checks import check_entity, estimate_bytes  # noqa: F401
