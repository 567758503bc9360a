"""Point-in-shape tests for the analytic shapes (Box, Sphere, Cylinder).

Used both for `fixed` regions (``points_in_region``) and for filling analytic
morphs (``points_in_shape``). Plain numpy, no Taichi.

Conventions:

* Boundaries are inclusive (a point exactly on the surface is inside), with a
  tolerance of 1e-9 of the shape's size so that round-off on lattice points
  does not decide membership.
* In 2D a ``Sphere`` is a disk. A ``Cylinder`` is 3D only: it is rejected in 2D
  with a ``ValueError`` (use a Box for a rectangle, a Sphere for a disk).
"""

from __future__ import annotations

import math

import numpy as np

from simcli.scene.morphs import BoxShape, CylinderShape, SphereShape

_REL_TOL = 1e-9


def _check_len(shape, name: str, vec, dim: int) -> np.ndarray:
    arr = np.asarray(vec, dtype=np.float64)
    if arr.shape != (dim,):
        raise ValueError(
            f"{shape.type}.{name} has {arr.size} components but the scene is {dim}D "
            f"(expected {dim}: {list(vec)})"
        )
    return arr


def check_shape_dim(shape, dim: int) -> None:
    """Raise ValueError if an analytic shape does not fit the dimension `dim`."""
    if isinstance(shape, BoxShape):
        lo, hi = shape.bounds()
        _check_len(shape, "lower" if shape.lower is not None else "center", lo, dim)
        _check_len(shape, "upper" if shape.upper is not None else "size", hi, dim)
    elif isinstance(shape, SphereShape):
        _check_len(shape, "center", shape.center, dim)
    elif isinstance(shape, CylinderShape):
        if dim != 3:
            raise ValueError(
                "Cylinder is a 3D shape and cannot be used in a 2D scene "
                "(use a Box for a rectangle or a Sphere for a disk)"
            )
        _check_len(shape, "center", shape.center, dim)
    else:
        raise TypeError(f"not an analytic shape: {getattr(shape, 'type', type(shape).__name__)}")


def shape_volume(shape, dim: int) -> float:
    """Exact volume (area in 2D) of an analytic shape [m^dim]."""
    check_shape_dim(shape, dim)
    if isinstance(shape, BoxShape):
        lo, hi = shape.bounds()
        return float(np.prod(np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64)))
    if isinstance(shape, SphereShape):
        r = float(shape.radius)
        return math.pi * r * r if dim == 2 else 4.0 / 3.0 * math.pi * r**3
    if isinstance(shape, CylinderShape):
        return math.pi * float(shape.radius) ** 2 * float(shape.height)
    raise ValueError(f"not an analytic shape: {shape!r}")


def points_in_shape(shape, x: np.ndarray) -> np.ndarray:
    """Boolean mask (n,) of the points `x` (n, dim) inside the analytic `shape` (boundary included)."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"points must be an (n, dim) array, got shape {x.shape}")
    dim = x.shape[1]
    check_shape_dim(shape, dim)
    if isinstance(shape, BoxShape):
        lo, hi = (np.asarray(b, dtype=np.float64) for b in shape.bounds())
        tol = _REL_TOL * float(np.max(hi - lo))
        return np.all((x >= lo - tol) & (x <= hi + tol), axis=1)
    if isinstance(shape, SphereShape):
        c = np.asarray(shape.center, dtype=np.float64)
        r = float(shape.radius)
        d2 = np.sum((x - c) ** 2, axis=1)
        return d2 <= (r * (1.0 + _REL_TOL)) ** 2
    if isinstance(shape, CylinderShape):
        c = np.asarray(shape.center, dtype=np.float64)
        ax = "xyz".index(shape.axis)
        r = float(shape.radius)
        d = x - c
        along = d[:, ax]
        radial2 = np.sum(d**2, axis=1) - along**2
        tol = _REL_TOL * max(r, float(shape.height))
        return (np.abs(along) <= shape.height / 2.0 + tol) & (radial2 <= (r + tol) ** 2)
    raise ValueError(f"not an analytic shape: {shape!r}")


def points_in_region(region, x: np.ndarray) -> np.ndarray:
    """Boolean mask (n,) of the points `x` (n, dim) inside a `fixed` region (Box, Sphere or Cylinder)."""
    return points_in_shape(region, x)


def points_in_regions(regions, x: np.ndarray) -> np.ndarray:
    """Boolean mask (n,) of the points inside any of `regions` (an empty list gives all False)."""
    x = np.asarray(x, dtype=np.float64)
    mask = np.zeros(x.shape[0], dtype=bool)
    for region in regions or []:
        mask |= points_in_region(region, x)
    return mask
