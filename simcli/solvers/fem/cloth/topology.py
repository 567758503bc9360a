"""Sheet meshes of FEM.Cloth entities (numpy, no Taichi): the Rectangle and open triangle Mesh morphs and
the bending hinges come from simcli.geometry.sheet, the same construction PBD.Cloth uses, so a PBD.Cloth and
a FEM.Cloth of one morph share their mesh."""

from __future__ import annotations

import numpy as np

from simcli.geometry.sheet import (  # noqa: F401 (re-exported for the cloth model and tests)
    bending_quads,
    dihedral_angles,
    read_open_surface,
    rectangle_mesh,
    sheet_axes,
)


def cloth_mesh(e, scene_dir) -> tuple[np.ndarray, np.ndarray]:
    m = e.morph
    if m.type == "Rectangle":
        return rectangle_mesh(m)
    if m.type == "Mesh":
        return read_open_surface(m, scene_dir)
    raise ValueError(f"entity '{e.name}': FEM.Cloth takes Rectangle or triangle Mesh morphs, not {m.type}")
