"""FEM.Cloth against `type: Sphere` and `type: Cylinder` colliders (issue 21: no intersection at any frame
with a collider). A signed distance per cloth vertex keeps the vertices out, not the edges and triangles:
a Cylinder's rims cut a sheet draped over them, and a coarse sheet's edges (longer than about
sqrt(8 R contact_distance)) dip into a Sphere. Every check here is independent of the solver's own
triangulation of the collider: the Sphere's exact surface (the distance from its centre to the cloth's
triangles, simcli.collider_mesh.mesh_distance) and, for the Cylinder, a fine inscribed prism built here
(1024 sides: 1 um inside the exact surface at r = 0.1 m) with the segment-triangle test
(geometry.edge_triangle_intersections) plus every vertex outside the exact cylinder. Small sheets, a few
substeps (host numpy/scipy/ipctk only, no Taichi)."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

pytest.importorskip("ipctk")
pytest.importorskip("scipy")

from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections  # noqa: E402
from tests.unit.test_fem_cloth import _solver  # noqa: E402

SCENE = """\
version: 1
sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.3}
domain: {lower: [-0.5, -0.5, 0], upper: [0.5, 0.5, 0.6]}
colliders:
  - {name: body, %(collider)s, friction: %(mu)s%(motion)s}
solvers:
  fem: {contact_distance: %(dhat)s}
entities:
  - name: c
    material: {type: FEM.Cloth, E: 1.0e5, nu: 0.3, rho: 200, thickness: 1.0e-3, friction: 0.2}
    morph: {type: Rectangle, center: %(center)s, size: %(size)s, resolution: %(res)s}
"""

SPHERE = "type: Sphere, center: [0, 0, 0.2], radius: 0.1"
CYLINDER = "type: Cylinder, center: [0, 0, 0.15], radius: 0.1, height: 0.2, axis: z"


def _scene(tmp_path, **kw):
    d = dict(
        collider=CYLINDER,
        mu=0.3,
        motion="",
        dhat="2.0e-3",
        center="[0.01, 0.02, 0.31]",
        size="[0.16, 0.16]",
        res=6,
    )
    d.update(kw)
    p = tmp_path / "cloth.yaml"
    p.write_text(textwrap.dedent(SCENE % d))
    return p


def _fine_cylinder(center, radius, height, n=1024):
    """An inscribed prism of the z-axis cylinder with n sides and fan caps (the test's own, independent of
    the solver's)."""
    a = 2 * np.pi * np.arange(n) / n
    ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(n)], 1)
    lo, hi = ring + [0, 0, -height / 2], ring + [0, 0, height / 2]
    V = np.concatenate([lo, hi, [[0, 0, -height / 2], [0, 0, height / 2]]]) + np.asarray(center)
    i = np.arange(n)
    j = (i + 1) % n
    T = np.concatenate(
        [
            np.stack([i, j, n + j], 1),
            np.stack([i, n + j, n + i], 1),
            np.stack([np.full(n, 2 * n), j, i], 1),
            np.stack([np.full(n, 2 * n + 1), n + i, n + j], 1),
        ]
    )
    return V, T


def _cylinder_crossings(x, tris, center, radius, height):
    """Cloth-cylinder crossings: a cloth edge through the fine prism's triangles or a prism edge (its rims)
    through a cloth triangle, plus cloth vertices inside the exact cylinder."""
    V, T = _fine_cylinder(center, radius, height)
    n = len(x)
    hits = [
        h
        for h in edge_triangle_intersections(np.concatenate([x, V]), np.concatenate([tris, T + n]))
        if (h[0][0] < n) == (h[1] >= len(tris))  # cloth against cylinder, not the cloth's own
    ]
    y = x - np.asarray(center)
    inside = (np.hypot(y[:, 0], y[:, 1]) < radius) & (np.abs(y[:, 2]) < height / 2)
    return len(hits) + int(inside.sum())


def _sphere_depth(x, tris, center, radius):
    """How far the cloth's triangles reach inside the exact sphere [m] (<= 0: outside): radius minus the
    distance from the centre to the nearest point of any cloth triangle."""
    from simcli.collider_mesh import mesh_distance

    return radius - float(mesh_distance(x, tris, np.asarray([center], float))[0])


def test_a_sheet_draped_over_a_cylinder_rim_is_never_cut_by_it(tmp_path):
    """A 0.4 m sheet (8 x 8 cells) dropped onto a 0.2 m-wide upright cylinder drapes over its top rim: the
    rim must not cut the sheet's triangles at any substep (a signed distance per vertex let it)."""
    p = _scene(tmp_path, size="[0.4, 0.4]", res=8, center="[0.0, 0.0, 0.26]")
    s = _solver(p)
    for k in range(14):
        s.substep(0.01)
        assert np.isfinite(s.x).all()
        assert _cylinder_crossings(s.x, s.tris, [0, 0, 0.15], 0.1, 0.2) == 0, ("crossings at substep", k + 1)
        assert edge_triangle_intersections(s.x, s.tris) == []
    assert s.x[:, 2].min() < 0.25 - 0.03  # it did drape over the rim (the corners hang below the top)


def test_a_coarse_sheet_draped_over_a_sphere_stays_outside_it(tmp_path):
    """A 0.4 m sheet with 5 cm edges (longer than sqrt(8 R contact_distance) = 4 cm) dropped onto a 0.1 m
    sphere: no triangle of it may reach inside the exact sphere at any substep (vertices alone were kept
    out: the edges between them dipped in by up to their sagitta l^2 / (8 R))."""
    p = _scene(tmp_path, collider=SPHERE, size="[0.4, 0.4]", res=8, center="[0.0, 0.0, 0.305]")
    s = _solver(p)
    for k in range(14):
        s.substep(0.01)
        assert np.isfinite(s.x).all()
        assert _sphere_depth(s.x, s.tris, [0, 0, 0.2], 0.1) <= 0.0, ("inside the sphere at substep", k + 1)
        assert edge_triangle_intersections(s.x, s.tris) == []
    assert s.x[:, 2].min() < 0.3 - 0.03  # it did drape over the sphere
