"""Morph -> particles (no Taichi): lattice fill of Box/Sphere/Cylinder/Mesh morphs,
closed-mesh loading and inside test, and point-in-region tests for `fixed` regions."""

from simcli.geometry.mesh import MeshError, MeshFileNotFoundError, mesh_bounds
from simcli.geometry.regions import points_in_region, points_in_regions
from simcli.geometry.sampling import (
    Body,
    estimate_particle_count,
    morph_bounds,
    morph_volume,
    sample_entity,
    sample_scene,
)

__all__ = [
    "Body",
    "MeshError",
    "MeshFileNotFoundError",
    "estimate_particle_count",
    "mesh_bounds",
    "morph_bounds",
    "morph_volume",
    "points_in_region",
    "points_in_regions",
    "sample_entity",
    "sample_scene",
]
