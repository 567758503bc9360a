"""FEM scene checks and memory estimate (numpy, no Taichi); the meshes themselves are built by
``simcli.geometry.tetmesh``."""

from __future__ import annotations

from simcli.geometry.tetmesh import read_tets
from simcli.scene.morphs import CylinderShape, MeshShape, SphereShape

# Bytes per vertex / per tetrahedron at f32 (f64 doubles the Taichi part): Taichi fields (explicit:
# x, v, rest x, free, prescribed v, dead load, mass, adjacency start, vertex outputs; per tet: indices, B,
# volume, material, corner forces, adjacency, outputs, muscle data) plus the host copies (numpy f64) kept
# by the solver; implicit adds 8 vectors + a 3x3 preconditioner per vertex and the singular-value-frame
# Hessian data (U, V, 3x3 block, 6 eigenvalues) and 4 diagonal 3x3 blocks per tet.
_FEM_VERTEX = {"explicit": (4 * 22, 160), "implicit": (4 * 59, 160)}  # (Taichi at f32, host)
_FEM_TET = {"explicit": (4 * 32 + 36, 250), "implicit": (4 * 101 + 36, 250)}
# measured (peak RSS, 1 step, f32): 40^3 Box minus 10^3 Box (67,590 vertices, 378,000 tets more): explicit
# +177 MB (estimate 173 MB), implicit +272 MB (estimate 287 MB)


def estimate_bytes(n_vertices: int, n_tets: int, integrator: str, precision: str) -> int:
    fp = 2 if precision == "f64" else 1
    kind = "explicit" if integrator == "explicit" else "implicit"  # backward_euler, implicit_midpoint
    (vt, vh), (tt, th) = _FEM_VERTEX[kind], _FEM_TET[kind]
    return n_vertices * (vt * fp + vh) + n_tets * (tt * fp + th)


def check_entity(entity, dim: int, scene_dir=None) -> list[tuple[tuple, str]]:
    """Scene-check findings for an FEM entity: (path below the entity, message)."""
    if dim != 3:
        return [(("material", "type"), f"{entity.material.type} entities need a 3D scene (sim.dim: 3)")]
    m = entity.morph
    needs_tetgen = isinstance(m, (SphereShape, CylinderShape))
    if isinstance(m, MeshShape):
        try:
            needs_tetgen = read_tets(m, scene_dir) is None
        except Exception:  # unreadable: reported by the morph checks
            needs_tetgen = False
    if needs_tetgen:
        import importlib.util

        if importlib.util.find_spec("tetgen") is None:
            return [
                (
                    ("morph", "type"),
                    f"{m.type} morphs of FEM entities are tetrahedralised with TetGen, whose Python package "
                    "'tetgen' (pyvista/tetgen, AGPL-3.0) is not installed: pip install tetgen; or give a "
                    "tetrahedral mesh file (.msh, .vtu, .mesh) as a Mesh morph, or use a Box morph",
                )
            ]
    return []


def check_linear_solver(scene) -> list[tuple[tuple, str]]:
    """solvers.fem.linear_solver: cholmod needs the optional packages (simcli.solvers.fem.cloth.checks), in a
    scene with FEM.Cloth entities (the only ones it serves)."""
    from simcli.solvers.fem.cloth.checks import cholmod_available

    if scene.solvers.fem.linear_solver != "cholmod" or cholmod_available():
        return []
    if not any(e.material.type == "FEM.Cloth" for e in scene.entities):
        return []
    return [
        (
            ("solvers", "fem", "linear_solver"),
            "linear_solver: cholmod needs the optional packages cvxopt and threadpoolctl "
            "(pip install 'simcli[cholmod]'); or use auto or superlu",
        )
    ]


def check_cloth_entity(entity, dim: int, scene_dir, scene) -> list[tuple[tuple, str]]:
    """Scene-check findings for a FEM.Cloth entity (simcli.solvers.fem.cloth.checks)."""
    from simcli.solvers.fem.cloth.checks import check_entity

    return check_entity(entity, dim, scene_dir, scene)


def check_element(scene) -> list[tuple[tuple, str]]:
    """``solvers.fem.element: tet10`` findings (path from the scene root, message): quadratic tetrahedra
    support FEM.Elastic solids only (simcli/solvers/fem/tet10.py)."""
    fem = getattr(scene.solvers, "fem", None)
    if fem is None or getattr(fem, "element", "tet4") != "tet10":
        return []
    out = []
    solids = [i for i, e in enumerate(scene.entities) if e.family == "FEM"]
    for i, e in enumerate(scene.entities):
        t = e.material.type
        if t == "FEM.Muscle":
            out.append(
                (
                    ("entities", i, "material", "type"),
                    "FEM.Muscle is not supported with solvers.fem.element: tet10 (the active fibre stress "
                    "is implemented for linear tetrahedra only): set solvers.fem.element: tet4 or use "
                    "FEM.Elastic",
                )
            )
        elif t == "FEM.Cloth":
            out.append(
                (
                    ("entities", i, "material", "type"),
                    "FEM.Cloth in a scene with solvers.fem.element: tet10 is not supported (the cloth "
                    "solver has triangles of its own and is not coupled to quadratic solids): set "
                    "solvers.fem.element: tet4 or move the cloth to a scene of its own",
                )
            )
        elif solids and e.family != "FEM":
            out.append(
                (
                    ("entities", i, "material", "type"),
                    f"{t} entities are not coupled to quadratic FEM solids (solvers.fem.element: tet10 "
                    "couples with no other family yet): set solvers.fem.element: tet4 to couple them, or "
                    "remove the "
                    f"{e.family} entities",
                )
            )
    if solids:
        for k, em in enumerate(getattr(scene, "emitters", []) or []):
            out.append(
                (
                    ("emitters", k),
                    "emitters are not coupled to quadratic FEM solids (solvers.fem.element: tet10): set "
                    "solvers.fem.element: tet4 or remove the emitter",
                )
            )
    return out
