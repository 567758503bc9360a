"""Host-side topology of PBD bodies (numpy, no Taichi): sheet and polyline meshes, their stretch and
bending constraints with rest values from the rest shape, lumped masses, and the graph colouring
that lets Gauss-Seidel sweeps run in parallel.

Dihedral angle and its gradient (Bridson, Marino and Fedkiw 2003, "Simulation of clothing with
folds and wrinkles", sec. 4): for the interior edge (x3, x4) between the triangles (x1, x3, x4) and
(x2, x4, x3), E = x4 - x3, n1 = (x1 - x3) x (x1 - x4), n2 = (x2 - x4) x (x2 - x3) and the signed angle
theta = atan2((n1^ x n2^) . E^, n1^ . n2^) (0 for a flat sheet). Its gradient is
  d theta/dx1 = -|E| n1 / |n1|^2,   d theta/dx2 = -|E| n2 / |n2|^2,
  d theta/dx3 = -((x1 - x4).E n1 / |n1|^2 + (x2 - x4).E n2 / |n2|^2) / |E|,
  d theta/dx4 = +((x1 - x3).E n1 / |n1|^2 + (x2 - x3).E n2 / |n2|^2) / |E|
(the four sum to zero: bending moves no centre of mass); tests check it against finite differences.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from simcli.geometry.regions import points_in_regions
from simcli.geometry.sheet import (  # noqa: F401 (shared with FEM.Cloth; re-exported for PBD's callers)
    bending_quads,
    dihedral_angles,
    read_open_surface,
    rectangle_mesh,
    sheet_axes,
)


@dataclass
class PBDMesh:
    """One PBD body: vertices, output cells and its constraints (vertex indices local to the body)."""

    x: np.ndarray  # (n, 3) rest positions [m]
    mass: np.ndarray  # (n,) lumped vertex masses [kg]
    kind: str  # "triangles" | "lines"
    cells: np.ndarray  # (m, 3) triangles or (m, 2) segments, for output
    stretch: np.ndarray  # (k, 2) distance constraints
    stretch_rest: np.ndarray  # (k,) rest lengths [m]
    bend_dist: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))  # rods: i, i + 2
    bend_dist_rest: np.ndarray = field(default_factory=lambda: np.zeros(0))
    dihedral: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))  # x1, x2, x3, x4
    dihedral_rest: np.ndarray = field(default_factory=lambda: np.zeros(0))  # rest angles [rad]
    tets: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))  # volume constraints
    tets_rest: np.ndarray = field(default_factory=lambda: np.zeros(0))  # rest volumes [m^3]
    radius: float = 0.0  # contact radius of a rod [m] (0: from solvers.pbd.particle_size)
    meshed: bool = True  # vertices joined by constraints (False: free particles)

    @property
    def n(self) -> int:
        return int(self.x.shape[0])


# ------------------------------------------------------------------ shapes


def line_vertices(morph) -> np.ndarray:
    """``segments + 1`` vertices spread at equal arc length along the Line's polyline."""
    p = np.asarray(morph.points, dtype=np.float64)
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if morph.segments is None:
        return p.copy()
    t = np.linspace(0.0, s[-1], morph.segments + 1)
    return np.stack([np.interp(t, s, p[:, k]) for k in range(p.shape[1])], axis=1)


# ------------------------------------------------------------- constraints


def unique_edges(tris: np.ndarray) -> np.ndarray:
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def dihedral_gradient(x1, x2, x3, x4) -> np.ndarray:
    """Gradient (4, 3) of the signed dihedral angle of one quad (module docstring)."""
    E = x4 - x3
    le = np.linalg.norm(E)
    n1 = np.cross(x1 - x3, x1 - x4)
    n2 = np.cross(x2 - x4, x2 - x3)
    a1 = n1 / n1.dot(n1)
    a2 = n2 / n2.dot(n2)
    g1 = -le * a1
    g2 = -le * a2
    g3 = -((x1 - x4).dot(E) * a1 + (x2 - x4).dot(E) * a2) / le
    g4 = ((x1 - x3).dot(E) * a1 + (x2 - x3).dot(E) * a2) / le
    return np.stack([g1, g2, g3, g4])


def colour(constraints: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Greedy graph colouring: no two constraints of one colour share a vertex, so each colour is solved
    in parallel and the colours one after another (a Gauss-Seidel sweep). Returns the permutation that
    groups constraints by colour and the colour offsets (ncolours + 1)."""
    k = constraints.shape[0]
    if k == 0:
        return np.zeros(0, np.int64), np.zeros(1, np.int64)
    used = [0] * n_vertices  # bit mask of the colours already touching each vertex
    col = np.empty(k, np.int64)
    cons = constraints.tolist()
    for c, vs in enumerate(cons):
        mask = 0
        for v in vs:
            mask |= used[v]
        free = ~mask & (mask + 1)  # lowest zero bit
        col[c] = free.bit_length() - 1
        for v in vs:
            used[v] |= free
    order = np.argsort(col, kind="stable")
    offsets = np.concatenate([[0], np.cumsum(np.bincount(col))]).astype(np.int64)
    return order, offsets


# ---------------------------------------------------------------- bodies


def tet_volumes(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a = x[tets[:, 0]]
    return np.einsum("ij,ij->i", np.cross(x[tets[:, 1]] - a, x[tets[:, 2]] - a), x[tets[:, 3]] - a) / 6.0


def mesh_for_entity(e, scene_dir, opts, dim: int = 3) -> PBDMesh:
    """The PBD mesh of an entity: a cloth sheet (Rectangle, open or closed triangle Mesh), a rod (Line),
    a tetrahedral soft body (PBD.Elastic solids, meshed as FEM does) or free particles (PBD.Particle).
    opts: the scene's solvers.pbd (the caller passes it: this module does not import config.py, which
    imports it). ``dim``: 2 for free particles in a 2D scene (mass per metre of depth: rho x area / count)."""
    m = e.morph
    mat = e.material
    if mat.type in ("PBD.Particle", "PBD.Liquid"):
        from simcli.geometry.sampling import sample_morph

        x, volume, _ = sample_morph(m, opts.particle_size, dim, scene_dir)
        n = len(x)
        if n == 0:
            raise ValueError(
                f"entity '{e.name}' got no particles: its morph is thinner than solvers.pbd.particle_size"
            )
        z2 = np.zeros((0, 2), np.int64)
        return PBDMesh(
            x=x,
            mass=np.full(n, mat.rho * volume / n),
            kind="particles",
            cells=np.zeros((0, 1)),
            stretch=z2,
            stretch_rest=np.zeros(0),
            meshed=False,
        )
    if mat.type == "PBD.Elastic" and m.type != "Line":
        from simcli.geometry.tetmesh import mesh_for_entity as tet_mesh
        from simcli.scene.meshing import Meshing

        tm = tet_mesh(e, Meshing(resolution=opts.tet_resolution), scene_dir)
        x, tets = tm.x, tm.tets
        vol = tet_volumes(x, tets)
        mass = np.zeros(len(x))
        for a in range(4):
            np.add.at(mass, tets[:, a], 0.25 * mat.rho * vol)
        pairs = np.concatenate([tets[:, [a, b]] for a in range(4) for b in range(a + 1, 4)])
        edges = np.unique(np.sort(pairs, axis=1), axis=0)
        return PBDMesh(
            x=x,
            mass=mass,
            kind="tets",
            cells=tets,
            stretch=edges,
            stretch_rest=np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1),
            tets=tets,
            tets_rest=vol,
        )
    if m.type in ("Rectangle", "Mesh"):
        x, tris = rectangle_mesh(m) if m.type == "Rectangle" else read_open_surface(m, scene_dir)
        area = 0.5 * np.linalg.norm(
            np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]), axis=1
        )
        mass = np.zeros(len(x))
        for a in range(3):
            np.add.at(mass, tris[:, a], mat.rho * area / 3.0)
        edges = unique_edges(tris)
        quads = bending_quads(tris)
        return PBDMesh(
            x=x,
            mass=mass,
            kind="triangles",
            cells=tris,
            stretch=edges,
            stretch_rest=np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1),
            dihedral=quads,
            dihedral_rest=dihedral_angles(x, quads),
        )
    if m.type == "Line":
        x = line_vertices(m)
        n = len(x)
        seg = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
        length = float(np.linalg.norm(np.diff(x, axis=0), axis=1).sum())
        mass = np.full(n, mat.rho * np.pi * m.radius**2 * length / n)
        skip = np.stack([np.arange(n - 2), np.arange(2, n)], axis=1) if n > 2 else np.zeros((0, 2), np.int64)
        return PBDMesh(
            x=x,
            mass=mass,
            kind="lines",
            cells=seg,
            stretch=seg,
            stretch_rest=np.linalg.norm(x[seg[:, 1]] - x[seg[:, 0]], axis=1),
            bend_dist=skip,
            bend_dist_rest=np.linalg.norm(x[skip[:, 1]] - x[skip[:, 0]], axis=1),
            radius=float(m.radius),
        )
    raise ValueError(f"entity '{e.name}': {e.material.type} does not take {m.type} morphs")


def fixed_vertices(e, x: np.ndarray) -> np.ndarray:
    return points_in_regions(e.fixed_regions, x)
