"""Particle sampling of morphs (simcli.geometry): lattice fill, exact mass, meshes, regions."""

from __future__ import annotations

import math
from pathlib import Path

import meshio
import numpy as np
import pytest

from simcli.geometry.mesh import (
    MeshError,
    MeshFileNotFoundError,
    TriMesh,
    lattice_inside_mesh,
    load_mesh_morph,
    points_inside_mesh,
    rotation_matrix,
    signed_volume,
)
from simcli.geometry.regions import points_in_region
from simcli.geometry.sampling import (
    estimate_particle_count,
    lattice_for_bounds,
    morph_bounds,
    sample_entity,
    sample_scene,
)
from simcli.scene.models import Scene

DATA = Path(__file__).resolve().parents[1] / "data"
RHO = 1000.0


# ------------------------------------------------------------------ mesh makers


def icosphere(subdivisions: int = 3, radius: float = 1.0):
    t = (1.0 + 5**0.5) / 2.0
    V = np.array(
        [
            [-1, t, 0],
            [1, t, 0],
            [-1, -t, 0],
            [1, -t, 0],
            [0, -1, t],
            [0, 1, t],
            [0, -1, -t],
            [0, 1, -t],
            [t, 0, -1],
            [t, 0, 1],
            [-t, 0, -1],
            [-t, 0, 1],
        ],
        dtype=float,
    )
    F = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ]
    )
    V /= np.linalg.norm(V, axis=1)[:, None]
    for _ in range(subdivisions):
        e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        ue, inv = np.unique(e, axis=0, return_inverse=True)
        mid = V[ue[:, 0]] + V[ue[:, 1]]
        mid /= np.linalg.norm(mid, axis=1)[:, None]
        m = inv.reshape(3, -1).T + len(V)
        V = np.concatenate([V, mid])
        a, b, c = F.T
        ab, bc, ca = m.T
        F = np.concatenate([np.stack(s, 1) for s in ([a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca])])
    return V * radius, F


def box_mesh(lo, hi, n: int = 1, quads: bool = False):
    """Closed box surface, each face split into n x n quads (duplicate vertices on the
    face borders are left for the loader to merge)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    lin = [np.linspace(lo[a], hi[a], n + 1) for a in range(3)]
    pts, cells = [], []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for side, val in ((-1, lo[a]), (1, hi[a])):
            U, W = np.meshgrid(lin[b], lin[c], indexing="ij")
            P = np.zeros((U.size, 3))
            P[:, a], P[:, b], P[:, c] = val, U.ravel(), W.ravel()
            idx = np.arange(U.size).reshape(U.shape) + sum(len(p) for p in pts)
            q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
            if side < 0:
                q = q[:, ::-1]
            pts.append(P)
            cells.append(q)
    P, Q = np.concatenate(pts), np.concatenate(cells)
    if quads:
        return P, [("quad", Q)]
    return P, [("triangle", np.concatenate([Q[:, [0, 1, 2]], Q[:, [0, 2, 3]]]))]


def torus(R=0.2, r=0.06, nu=96, nv=48):
    u = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    v = np.linspace(0, 2 * np.pi, nv, endpoint=False)
    U, W = np.meshgrid(u, v, indexing="ij")
    P = np.stack([(R + r * np.cos(W)) * np.cos(U), (R + r * np.cos(W)) * np.sin(U), r * np.sin(W)], -1)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j
    c = ((i + 1) % nu) * nv + (j + 1) % nv
    d = i * nv + (j + 1) % nv
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return P.reshape(-1, 3), F


def write_mesh(path: Path, points, cells) -> Path:
    if isinstance(cells, np.ndarray):
        cells = [("triangle", cells)]
    meshio.write(str(path), meshio.Mesh(np.asarray(points, float), cells))
    return path


# ---------------------------------------------------------------------- scenes


def make_scene(morph, dim=3, spacing=0.01, sampling="lattice", fixed=None, velocity=None, seed=0, extra=()):
    ent = {"name": "body", "material": {"type": "MPM.Elastic", "rho": RHO}, "morph": morph}
    if fixed is not None:
        ent["fixed"] = fixed
    if velocity is not None:
        ent["velocity"] = velocity
    return Scene.model_validate(
        {
            "sim": {"dim": dim, "seed": seed},
            "solvers": {"mpm": {"particle_size": spacing, "sampling": sampling}},
            "entities": [ent, *extra],
        }
    )


def sample(morph, scene_dir=".", **kw):
    scene = make_scene(morph, **kw)
    bodies = sample_scene(scene, scene_dir, scene.sim.seed)
    assert len(bodies) == 1
    return bodies[0]


def assert_body_consistent(b, dim):
    n = b.x.shape[0]
    assert b.x.shape == (n, dim) and b.v.shape == (n, dim)
    assert b.volume.shape == b.mass.shape == b.fixed.shape == (n,)
    assert b.fixed.dtype == bool


# ----------------------------------------------------------------------- tests


def test_box_count_and_exact_mass():
    b = sample({"type": "Box", "lower": [-0.1, -0.1, 0.3], "upper": [0.1, 0.1, 0.5]})
    assert_body_consistent(b, 3)
    assert b.n == 8000
    assert b.mass.sum() == pytest.approx(RHO * 0.2**3, rel=1e-12)
    assert b.volume.sum() == pytest.approx(0.2**3, rel=1e-12)
    # cell-centred, symmetric lattice
    assert np.allclose(b.x.min(axis=0), [-0.095, -0.095, 0.305])
    assert np.allclose(b.x.max(axis=0), [0.095, 0.095, 0.495])
    assert np.allclose(b.x.mean(axis=0), [0.0, 0.0, 0.4])
    assert not b.fixed.any() and np.all(b.v == 0)
    assert b.warnings == []


def test_box_center_size_and_non_multiple_extent():
    b = sample({"type": "Box", "center": [0, 0, 0.4], "size": [0.205, 0.1, 0.1]})
    lo, hi = np.array([-0.1025, -0.05, 0.35]), np.array([0.1025, 0.05, 0.45])
    assert b.n == 21 * 10 * 10
    assert np.all(b.x > lo) and np.all(b.x < hi)
    assert b.mass.sum() == pytest.approx(RHO * 0.205 * 0.01, rel=1e-12)


def test_sphere_exact_mass():
    r = 0.1
    b = sample({"type": "Sphere", "center": [0.0, 0.0, 0.5], "radius": r})
    assert b.mass.sum() == pytest.approx(RHO * 4.0 / 3.0 * math.pi * r**3, rel=1e-12)
    assert b.n == pytest.approx(4.0 / 3.0 * math.pi * r**3 / 0.01**3, rel=0.02)
    assert np.all(np.linalg.norm(b.x - [0, 0, 0.5], axis=1) <= r)
    assert np.allclose(b.x.mean(axis=0), [0, 0, 0.5], atol=1e-12)


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_cylinder_each_axis(axis):
    r, height = 0.05, 0.2
    b = sample({"type": "Cylinder", "center": [0.0, 0.0, 0.4], "radius": r, "height": height, "axis": axis})
    a = "xyz".index(axis)
    d = b.x - [0.0, 0.0, 0.4]
    along = d[:, a]
    radial = np.sqrt(np.sum(d**2, axis=1) - along**2)
    assert np.all(np.abs(along) <= height / 2) and np.all(radial <= r)
    assert np.ptp(along) == pytest.approx(height - 0.01)
    assert b.mass.sum() == pytest.approx(RHO * math.pi * r**2 * height, rel=1e-12)
    assert b.n == pytest.approx(math.pi * r**2 * height / 0.01**3, rel=0.05)
    lo, hi = morph_bounds(b.entity.morph)
    assert hi[a] - lo[a] == pytest.approx(height)


def test_2d_box_and_disk():
    b = sample({"type": "Box", "lower": [0.2, 0.2], "upper": [0.4, 0.3]}, dim=2)
    assert_body_consistent(b, 2)
    assert b.n == 20 * 10
    assert b.mass.sum() == pytest.approx(RHO * 0.02, rel=1e-12)
    d = sample({"type": "Sphere", "center": [0.5, 0.5], "radius": 0.1}, dim=2)
    assert_body_consistent(d, 2)
    assert d.mass.sum() == pytest.approx(RHO * math.pi * 0.01, rel=1e-12)
    assert d.n == pytest.approx(math.pi * 0.01 / 0.01**2, rel=0.03)


def test_2d_rejects_cylinder_and_mesh():
    with pytest.raises(ValueError, match="Cylinder.*3D"):
        sample({"type": "Cylinder", "center": [0.5, 0.5], "radius": 0.1, "height": 0.2}, dim=2)
    with pytest.raises(ValueError, match="Mesh morphs need a 3D scene"):
        sample({"type": "Mesh", "file": "whatever.obj"}, dim=2)


def test_dimension_mismatch_is_clear():
    with pytest.raises(ValueError, match="entity 'body'.*3 components.*2D"):
        sample({"type": "Box", "lower": [0, 0, 0], "upper": [0.1, 0.1, 0.1]}, dim=2)


def test_jitter_inside_and_reproducible():
    sph = {"type": "Sphere", "center": [0.0, 0.0, 0.5], "radius": 0.08}
    box = {"type": "Box", "lower": [-0.1025, -0.05, 0.3], "upper": [0.1, 0.05, 0.4]}
    lat = sample(sph)
    a = sample(sph, sampling="jitter", seed=3)
    b = sample(sph, sampling="jitter", seed=3)
    c = sample(sph, sampling="jitter", seed=4)
    assert a.n == lat.n  # the count does not depend on the seed
    assert np.array_equal(a.x, b.x)
    assert not np.array_equal(a.x, c.x)
    assert np.all(np.linalg.norm(a.x - [0, 0, 0.5], axis=1) <= 0.08)
    off = np.abs(a.x - lat.x)
    assert off.max() <= 0.3 * 0.01 + 1e-12 and off.mean() > 0.05 * 0.01
    assert a.mass.sum() == pytest.approx(lat.mass.sum(), rel=1e-12)
    j = sample(box, sampling="jitter", seed=1)
    assert np.all(j.x >= [-0.1025, -0.05, 0.3]) and np.all(j.x <= [0.1, 0.05, 0.4])


def test_velocity_and_fixed_regions():
    fixed = [
        {"type": "Box", "lower": [-0.1, -0.1, 0.3], "upper": [0.1, 0.1, 0.32]},
        {"type": "Sphere", "center": [0.1, 0.1, 0.5], "radius": 0.03},
    ]
    b = sample(
        {"type": "Box", "lower": [-0.1, -0.1, 0.3], "upper": [0.1, 0.1, 0.5]},
        fixed=fixed,
        velocity=[1.0, 0.0, -2.0],
    )
    assert np.all(b.v == [1.0, 0.0, -2.0])
    in_slab = b.x[:, 2] <= 0.32
    in_ball = np.linalg.norm(b.x - [0.1, 0.1, 0.5], axis=1) <= 0.03
    assert np.array_equal(b.fixed, in_slab | in_ball)
    assert in_slab.sum() == 2 * 400 and in_ball.any()
    # a region holding no particle is reported
    b2 = sample(
        {"type": "Box", "lower": [-0.1, -0.1, 0.3], "upper": [0.1, 0.1, 0.5]},
        fixed={"type": "Cylinder", "center": [0.3, 0.3, 0.4], "radius": 0.01, "height": 0.1},
    )
    assert not b2.fixed.any()
    assert any("fixed region" in w for w in b2.warnings)


def test_points_in_region_shapes():
    from simcli.scene.morphs import BoxShape, CylinderShape, SphereShape

    x = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.09], [0.0, 0.051, -0.01], [0.1, 0.1, 0.1]])
    cyl = CylinderShape(type="Cylinder", center=[0, 0, 0], radius=0.05, height=0.2, axis="z")
    assert points_in_region(cyl, x).tolist() == [True, True, False, False]
    box = BoxShape(type="Box", lower=[0, 0, 0], upper=[0.1, 0.1, 0.1])
    assert points_in_region(box, x).tolist() == [True, True, False, True]  # boundary included
    sph = SphereShape(type="Sphere", center=[0, 0], radius=0.05)
    assert points_in_region(sph, x[:, :2]).tolist() == [True, True, False, False]
    with pytest.raises(ValueError, match="3D shape"):
        points_in_region(CylinderShape(type="Cylinder", center=[0, 0], radius=1, height=1), x[:, :2])


def test_estimates_and_bounds():
    box = make_scene({"type": "Box", "lower": [-0.1, -0.1, 0.3], "upper": [0.1, 0.1, 0.5]}).entities[0].morph
    assert estimate_particle_count(box, 0.01, 3) == 8000
    sph = make_scene({"type": "Sphere", "center": [0, 0, 0.5], "radius": 0.1}).entities[0].morph
    assert estimate_particle_count(sph, 0.01, 3) == round(4 / 3 * math.pi * 1000)
    lo, hi = morph_bounds(sph)
    assert np.allclose(lo, [-0.1, -0.1, 0.4]) and np.allclose(hi, [0.1, 0.1, 0.6])
    origin, counts = lattice_for_bounds([0, 0], [0.2, 0.004], 0.01)
    assert counts.tolist() == [20, 1] and np.allclose(origin, [0.005, 0.002])


# ---------------------------------------------------------------------- meshes


def test_cube_mesh_exact(tmp_path):
    f = write_mesh(tmp_path / "cube.stl", *box_mesh([-0.1, -0.1, 0.3], [0.1, 0.1, 0.5], n=3))
    b = sample({"type": "Mesh", "file": "cube.stl"}, scene_dir=tmp_path)
    assert b.n == 8000
    assert b.mass.sum() == pytest.approx(RHO * 0.008, rel=1e-12)
    assert f.exists()


def test_cube_mesh_rays_through_edges_and_vertices(tmp_path):
    # 21 lattice points per axis at multiples of h: rays pass exactly through the face
    # diagonals and through mesh vertices; each crossing must be counted exactly once.
    h = 0.2 / 21
    for n, quads in ((1, False), (2, False), (4, True)):
        write_mesh(tmp_path / f"c{n}.obj", *box_mesh([-0.1] * 3, [0.1] * 3, n=n, quads=quads))
        b = sample({"type": "Mesh", "file": f"c{n}.obj"}, scene_dir=tmp_path, spacing=h)
        assert b.n == 21**3, n


def test_data_meshes_and_quads():
    b = sample({"type": "Mesh", "file": str(DATA / "cube.obj"), "scale": 0.2, "translate": [0, 0, 0.4]})
    assert b.n == 8000 and b.mass.sum() == pytest.approx(RHO * 0.008, rel=1e-12)


@pytest.mark.parametrize("fmt", ["obj", "stl", "ply", "off", "vtu"])
def test_icosphere_mesh(tmp_path, fmt):
    V, F = icosphere(3, radius=1.0)
    write_mesh(tmp_path / f"ico.{fmt}", V, F)
    r = 0.1
    b = sample(
        {"type": "Mesh", "file": f"ico.{fmt}", "scale": r, "translate": [0, 0, 0.5]}, scene_dir=tmp_path
    )
    vol = abs(signed_volume(V * r, F))
    assert vol == pytest.approx(4 / 3 * math.pi * r**3, rel=0.03)  # polyhedron slightly inside the sphere
    assert b.mass.sum() == pytest.approx(RHO * vol, rel=1e-9)
    assert b.n == pytest.approx(vol / 0.01**3, rel=0.03)
    assert np.all(np.linalg.norm(b.x - [0, 0, 0.5], axis=1) <= r)
    assert b.warnings == []


def test_icosphere_inside_matches_brute_force(tmp_path):
    V, F = icosphere(2)
    mesh = TriMesh(V, F, signed_volume(V, F))
    rng = np.random.default_rng(0)
    P = rng.uniform(-1.05, 1.05, size=(20000, 3))
    inside = points_inside_mesh(mesh, P)
    # exact reference: a point is inside the convex polyhedron iff it is behind every face plane
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(B - A, C - A)
    ref = np.all(np.einsum("fk,pk->pf", n, P) <= np.einsum("fk,fk->f", n, A)[None, :], axis=1)
    assert np.count_nonzero(inside != ref) == 0
    # the lattice version agrees with the point version
    origin, counts = lattice_for_bounds(V.min(0), V.max(0), 0.05)
    res = lattice_inside_mesh(mesh, origin, 0.05, counts)
    grid = np.stack(
        np.meshgrid(*[origin[a] + 0.05 * np.arange(counts[a]) for a in range(3)], indexing="ij"), -1
    )
    assert np.array_equal(res.inside.reshape(-1), points_inside_mesh(mesh, grid.reshape(-1, 3)))
    assert res.odd_rays == 0


def test_torus_nonconvex(tmp_path):
    R, r = 0.2, 0.06
    write_mesh(tmp_path / "torus.ply", *torus(R, r))
    b = sample({"type": "Mesh", "file": "torus.ply", "translate": [0, 0, 0.5]}, scene_dir=tmp_path)
    vol = 2 * math.pi**2 * R * r**2
    assert b.n == pytest.approx(vol / 0.01**3, rel=0.03)
    rho_ = np.hypot(b.x[:, 0], b.x[:, 1])
    assert np.all((rho_ - R) ** 2 + (b.x[:, 2] - 0.5) ** 2 <= r**2)
    assert not np.any(rho_ < R - r)  # the hole is empty
    j = sample(
        {"type": "Mesh", "file": "torus.ply", "translate": [0, 0, 0.5]},
        scene_dir=tmp_path,
        sampling="jitter",
        seed=7,
    )
    rj = np.hypot(j.x[:, 0], j.x[:, 1])
    assert j.n == b.n and np.all((rj - R) ** 2 + (j.x[:, 2] - 0.5) ** 2 <= r**2)


def test_mesh_transform_bounds(tmp_path):
    write_mesh(tmp_path / "brick.obj", *box_mesh([0, 0, 0], [1, 2, 3], n=1))
    morph = {
        "type": "Mesh",
        "file": "brick.obj",
        "scale": [0.1, 0.05, 0.02],
        "rotate": [0, 0, 90],
        "translate": [0.1, 0.2, 0.3],
    }
    m = make_scene(morph).entities[0].morph
    lo, hi = morph_bounds(m, tmp_path)
    # scaled: [0,0.1]x[0,0.1]x[0,0.06]; rotated 90 deg about z: (x, y) -> (-y, x); translated
    assert np.allclose(lo, [0.0, 0.2, 0.3]) and np.allclose(hi, [0.1, 0.3, 0.36])
    b = sample(morph, scene_dir=tmp_path)
    assert b.n == 10 * 10 * 6
    assert b.mass.sum() == pytest.approx(RHO * 0.1 * 0.1 * 0.06, rel=1e-9)
    assert np.all(b.x > lo) and np.all(b.x < hi)
    # extrinsic x then y then z: R = Rz Ry Rx
    Rx, Ry = rotation_matrix([90, 0, 0]), rotation_matrix([0, 90, 0])
    assert np.allclose(rotation_matrix([90, 90, 0]), Ry @ Rx)
    assert np.allclose(rotation_matrix([0, 0, 90]) @ [1, 0, 0], [0, 1, 0])
    # rotating the brick by (90, 0, 0) maps its z extent onto y
    m2 = make_scene({**morph, "rotate": [90, 0, 0], "translate": [0, 0, 0]}).entities[0].morph
    lo2, hi2 = morph_bounds(m2, tmp_path)
    assert np.allclose(hi2 - lo2, [0.1, 0.06, 0.1])


def test_inside_out_mesh_is_flipped(tmp_path):
    P, cells = box_mesh([0, 0, 0], [0.1, 0.1, 0.1])
    write_mesh(tmp_path / "inv.obj", P, cells[0][1][:, ::-1])
    b = sample({"type": "Mesh", "file": "inv.obj"}, scene_dir=tmp_path)
    assert b.n == 1000 and b.mass.sum() == pytest.approx(1.0, rel=1e-9)


def test_open_mesh_raises(tmp_path):
    P, cells = box_mesh([0, 0, 0], [0.1, 0.1, 0.1], n=1)
    write_mesh(tmp_path / "open.obj", P, np.delete(cells[0][1], [5, 11], axis=0))  # drop one face
    with pytest.raises(MeshError, match=r"open\.obj.*not a closed surface: 4 boundary edge"):
        sample({"type": "Mesh", "file": "open.obj"}, scene_dir=tmp_path)
    with pytest.raises(MeshError, match="boundary edge"):
        sample({"type": "Mesh", "file": str(DATA / "open_box.obj")})
    # inconsistent orientation: one triangle flipped
    T = cells[0][1].copy()
    T[0] = T[0, ::-1]
    write_mesh(tmp_path / "flip.stl", P, T)
    with pytest.raises(MeshError, match="opposite orientation"):
        sample({"type": "Mesh", "file": "flip.stl"}, scene_dir=tmp_path)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(MeshFileNotFoundError, match="mesh file not found: 'nope.obj'.*relative to the scene"):
        sample({"type": "Mesh", "file": "nope.obj"}, scene_dir=tmp_path)
    with pytest.raises(FileNotFoundError):
        morph_bounds(make_scene({"type": "Mesh", "file": "nope.obj"}).entities[0].morph, tmp_path)
    (tmp_path / "junk.xyz").write_text("hello")
    with pytest.raises(MeshError, match="cannot read mesh"):
        sample({"type": "Mesh", "file": "junk.xyz"}, scene_dir=tmp_path)


def test_thin_part_reported(tmp_path):
    # a 0.2 x 0.2 block with a 0.2 x 0.2 x 0.004 fin: the fin is thinner than the spacing
    P1, c1 = box_mesh([0, 0, 0], [0.1, 0.1, 0.1])
    P2, c2 = box_mesh([0.3, 0, 0.0405], [0.5, 0.2, 0.0445])
    write_mesh(tmp_path / "fin.obj", np.concatenate([P1, P2]), np.concatenate([c1[0][1], c2[0][1] + len(P1)]))
    b = sample({"type": "Mesh", "file": "fin.obj"}, scene_dir=tmp_path)
    assert b.mass.sum() == pytest.approx(RHO * (0.001 + 0.2 * 0.2 * 0.004), rel=1e-9)
    assert b.n == 1000  # the fin lies between two lattice planes
    assert any("thinner than the particle spacing" in w and "13.8%" in w for w in b.warnings)


def test_mesh_estimate_and_sample_scene_order(tmp_path):
    write_mesh(tmp_path / "ico.obj", *icosphere(2, radius=0.1))
    m = make_scene({"type": "Mesh", "file": "ico.obj"}).entities[0].morph
    est = estimate_particle_count(m, 0.01, 3, tmp_path)
    assert est == round(load_mesh_morph(m, tmp_path).volume / 1e-6)
    other = {
        "name": "b2",
        "material": {"type": "MPM.Elastic"},
        "morph": {"type": "Sphere", "center": [0, 0, 0.5], "radius": 0.05},
    }
    scene = make_scene({"type": "Mesh", "file": "ico.obj", "translate": [0, 0, 0.3]}, extra=[other])
    bodies = sample_scene(scene, tmp_path, 0)
    assert [b.name for b in bodies] == ["body", "b2"]
    assert bodies[0].n == pytest.approx(est, rel=0.05)
    single = sample_entity(scene.entities[1], scene, tmp_path, np.random.default_rng(0))
    assert np.array_equal(single.x, bodies[1].x)


def test_tetrahedral_mesh_uses_its_boundary(tmp_path):
    # [0, 0.1]^3 as 2 x 2 x 2 cubes of 6 Kuhn tetrahedra each, written as .vtu
    import itertools

    g = np.linspace(0.0, 0.1, 3)
    P = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    vid = lambda i, j, k: (i * 3 + j) * 3 + k
    tets = []
    for i, j, k in itertools.product(range(2), repeat=3):
        for perm in itertools.permutations(range(3)):
            c = [i, j, k]
            path = [vid(*c)]
            for a in perm:
                c[a] += 1
                path.append(vid(*c))
            tets.append(path)
    write_mesh(tmp_path / "cube_tets.vtu", P, [("tetra", np.array(tets))])
    b = sample({"type": "Mesh", "file": "cube_tets.vtu"}, scene_dir=tmp_path)
    assert b.n == 1000 and b.mass.sum() == pytest.approx(1.0, rel=1e-9)
