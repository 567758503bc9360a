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


def dihedral_gradients(x: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(k, 4, 3) gradients of the signed dihedral angles (Bridson et al. 2003, sec. 4; as
    simcli.solvers.pbd.topology)."""
    x1, x2, x3, x4 = (x[quads[:, k]] for k in range(4))
    E = x4 - x3
    le = np.linalg.norm(E, axis=1)
    n1 = np.cross(x1 - x3, x1 - x4)
    n2 = np.cross(x2 - x4, x2 - x3)
    a1 = n1 / np.einsum("ij,ij->i", n1, n1)[:, None]
    a2 = n2 / np.einsum("ij,ij->i", n2, n2)[:, None]
    dot = lambda a, b: np.einsum("ij,ij->i", a, b)[:, None]  # noqa: E731
    g1 = -le[:, None] * a1
    g2 = -le[:, None] * a2
    g3 = -(dot(x1 - x4, E) * a1 + dot(x2 - x4, E) * a2) / le[:, None]
    g4 = (dot(x1 - x3, E) * a1 + dot(x2 - x3, E) * a2) / le[:, None]
    return np.stack([g1, g2, g3, g4], axis=1)
