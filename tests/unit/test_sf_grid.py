"""Stable fluids, host side (no Taichi): options, jets on paths, scene checks, the MAC layout (face
kinds, Poisson diagonal, multigrid hierarchy) and the viscosity operator's matrix."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from simcli.errors import SceneError
from simcli.scene.loader import load_scene
from simcli.scene.models import Scene
from simcli.solvers.sf.config import Jet, SFOptions, estimate_bytes
from simcli.solvers.sf.grid import (
    DUP,
    FREE,
    OPEN_FACE,
    SOLID_FACE,
    WALL_HI,
    WALL_LO,
    collider_mask,
    compute_flags,
    fine_diagonal,
    make_layout,
    viscosity_operator,
)


def scene(**kw) -> Scene:
    d = {
        "sim": {"dim": 2, "gravity": [0.0, -9.81]},
        "domain": {"lower": [0, 0], "upper": [1, 1]},
        "solvers": {"sf": {"resolution": 8}},
        "entities": [{"name": "fluid", "material": {"type": "SF.Smoke"}}],
    }
    for k, v in kw.items():
        d[k] = v
    return Scene.model_validate(d)


def layout_of(s: Scene):
    L = make_layout(s, s.solvers.sf)
    compute_flags(L, collider_mask(s, L))
    return L


def test_resolution_is_cells_along_the_longest_axis():
    n, dx = SFOptions(resolution=64).cells([0, 0, 0], [1, 0.5, 2])
    assert n == [32, 16, 64] and np.allclose(dx, [1 / 32, 1 / 32, 1 / 32])
    n, dx = SFOptions(resolution=[10, 20]).cells([0, 0], [1, 1])
    assert n == [10, 20] and np.allclose(dx, [0.1, 0.05])


def test_orbit_jet_turns_its_vectors_with_it():
    jet = Jet.model_validate(
        {
            "position": [0.8, 0.5, 0.5],
            "radius": 0.05,
            "force": [-1.0, 0.0, 0.0],
            "path": {"type": "orbit", "center": [0.5, 0.5, 0.5], "axis": "y", "angular_velocity": 0.5},
        }
    )
    for t in (0.0, 1.0, 3.7):
        p, _, f, on = jet.state(t, 3)
        r = p - np.array([0.5, 0.5, 0.5])
        assert math.isclose(np.linalg.norm(r), 0.3, rel_tol=1e-12) and abs(r[1]) < 1e-12
        # the force was inward at t = 0 and stays inward
        assert np.allclose(f, -r / 0.3, atol=1e-12) and on == 1.0
    p, _, _, _ = jet.state(math.pi, 3)  # half a turn at 0.5 rad/s: a quarter of the circle
    assert np.allclose(p, [0.5, 0.5, 0.2], atol=1e-12)  # right-handed about y: x -> -z


def test_waypoint_jet_and_time_window():
    jet = Jet.model_validate(
        {
            "radius": 0.1,
            "density_rate": 1.0,
            "start": 1.0,
            "stop": 2.0,
            "path": {
                "type": "waypoints",
                "times": [0, 1, 3],
                "points": [[0, 0], [1, 0], [1, 2]],
                "periodic": True,
            },
        }
    )
    assert np.allclose(jet.state(0.5, 2)[0], [0.5, 0.0]) and jet.state(0.5, 2)[3] == 0.0
    assert np.allclose(jet.state(2.0, 2)[0], [1.0, 1.0]) and jet.state(1.5, 2)[3] == 1.0
    assert np.allclose(jet.state(3.5, 2)[0], [0.5, 0.0])  # periodic
    with pytest.raises(ValueError):
        Jet.model_validate({"radius": 0.1})


def test_morph_is_optional_only_for_sf():
    scene()  # no morph: fine
    with pytest.raises(ValueError, match="morph is required"):
        Scene.model_validate({"entities": [{"name": "b", "material": {"type": "MPM.Elastic"}}]})
    with pytest.raises(ValueError, match="jets are for SF.Smoke"):
        Scene.model_validate(
            {
                "entities": [
                    {
                        "name": "b",
                        "material": {"type": "MPM.Elastic"},
                        "morph": {"type": "Sphere", "center": [0, 0, 0.5], "radius": 0.1},
                        "jets": [{"position": [0, 0, 0.5], "radius": 0.1}],
                    }
                ]
            }
        )


def _write(tmp_path: Path, d: dict) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(d))
    return p


def _errors(tmp_path: Path, d: dict) -> str:
    with pytest.raises(SceneError) as e:
        load_scene(_write(tmp_path, d))
    return "\n".join(e.value.lines)


def test_scene_checks(tmp_path):
    base = {
        "sim": {"dim": 2},
        "domain": {"lower": [0, 0], "upper": [1, 1]},
        "entities": [{"name": "fluid", "material": {"type": "SF.Smoke"}}],
    }
    d = dict(base, domain={"lower": [0, 0], "upper": [1, 1], "faces": {"x-": {"type": "periodic"}}})
    assert "periodic faces come in pairs" in _errors(tmp_path, d)
    d = dict(
        base,
        domain={"lower": [0, 0], "upper": [1, 1], "boundary": {"type": "periodic"}},
        solvers={"sf": {"resolution": 9}},
    )
    assert "even number of cells" in _errors(tmp_path, d)
    d = dict(base, solvers={"sf": {"resolution": 40000}})
    assert "scene too large" in _errors(tmp_path, d) and "solvers.sf.resolution" in _errors(tmp_path, d)
    d = dict(base, entities=base["entities"] * 2)
    assert "one SF.Smoke entity" in _errors(tmp_path, d)
    d = dict(
        base,
        entities=[
            {
                "name": "fluid",
                "material": {"type": "SF.Smoke"},
                "jets": [{"position": [0.5, 0.5, 0.5], "radius": 0.1}],
            }
        ],
    )
    assert "jets.0.position: expected 2 components" in _errors(tmp_path, d)
    mpm = {
        "sim": {"dim": 2},
        "domain": {"lower": [0, 0], "upper": [1, 1], "faces": {"y+": {"type": "open"}}},
        "entities": [
            {
                "name": "b",
                "material": {"type": "MPM.Elastic"},
                "morph": {"type": "Box", "lower": [0.4, 0.4], "upper": [0.6, 0.6]},
            }
        ],
    }
    assert "'open' faces are for grid fluids (SF) only" in _errors(tmp_path, mpm)
    ok = dict(base, domain={"lower": [0, 0], "upper": [1, 1], "faces": {"y+": {"type": "open"}}})
    load_scene(_write(tmp_path, ok))


def test_memory_estimate_grows_with_the_grid():
    o = SFOptions()  # MacCormack, MGPCG
    a = estimate_bytes(o, None, [64, 64, 64])
    b = estimate_bytes(o, None, [128, 128, 128])
    c = estimate_bytes(o, None, [256, 256, 256])
    assert a < b < c and a < 0.5 * 2**30
    assert 7 < (c - b) / (b - a) < 9  # ~ cells
    assert 3.5 * 2**30 < c < 6 * 2**30  # measured: 4.7 GB peak RSS for the 256^3 hard case


def test_face_kinds_walls_lid_collider_open_periodic():
    s = scene(
        domain={
            "lower": [0, 0],
            "upper": [1, 1],
            "boundary": {"type": "sticky"},
            "faces": {"y+": {"type": "sticky", "velocity": [1.0, 0.0]}, "x-": {"type": "open"}},
        },
        colliders=[{"type": "Box", "lower": [0.5, 0.5], "upper": [0.8, 0.8]}],
    )
    L = layout_of(s)
    K0 = L.kinds[0][1:-1, 1:-1]  # u faces: (9, 8) valid
    K1 = L.kinds[1][1:-1, 1:-1]  # v faces: (8, 9)
    assert (K0[0, :8] == OPEN_FACE).all() and (K0[8, :8] == WALL_HI).all()
    assert (K1[:8, 0] == WALL_LO).all() and (K1[:8, 8] == WALL_HI).all()
    assert (K0[1:8, :8][(K0[1:8, :8] != SOLID_FACE)] == FREE).all()
    assert (K0 == SOLID_FACE).sum() > 0 and L.wall_velocity[1, 1, 0] == 1.0
    # the Poisson diagonal: open faces weigh 2, walls and colliders 0
    D = fine_diagonal(L)
    c = 1 / L.dx[0] ** 2
    assert math.isclose(D[3, 3], 4 * c) and math.isclose(D[1, 1], 4 * c)
    assert math.isclose(D[0, 3], 5 * c)  # open face (2) + right, top, bottom (1 each)
    assert math.isclose(D[0, 0], 4 * c)  # open (2) + right (1) + top (1), none through the wall below
    assert math.isclose(D[1, 0], 3 * c)  # next to the bottom wall: no coupling through it
    assert (D[collider_mask(s, L)] == 0).all()

    p = layout_of(scene(domain={"lower": [0, 0], "upper": [1, 1], "boundary": {"type": "periodic"}}))
    assert (p.kinds[0][1 + 8, 1:-1][:8] == DUP).all() and np.allclose(fine_diagonal(p), 4 / p.dx[0] ** 2)


def test_multigrid_hierarchy_halves_down_to_a_few_cells():
    L = layout_of(scene(solvers={"sf": {"resolution": 64}}, domain={"lower": [0, 0], "upper": [2, 1]}))
    assert [lv.n for lv in L.levels] == [(64, 32), (32, 16), (16, 8), (8, 4), (4, 2)]
    assert all(np.isclose(b.c[0], 2 * a.c[0]) for a, b in zip(L.levels, L.levels[1:]))  # 2^(d-1)


def _matrix(L, d):
    """Dense viscosity matrix K-part of component d on its unknown faces: (diag K, -c off-diagonal)."""
    K, B = viscosity_operator(L, d)
    idx = {tuple(i): k for k, i in enumerate(np.argwhere(K >= 0))}
    M = np.zeros((len(idx), len(idx)))
    c = [1 / h**2 for h in L.dx]
    n = L.n
    for i, k in idx.items():
        M[k, k] = K[i]
        for a in range(L.dim):
            for s in (1, -1):
                j = list(i)
                j[a] += s
                if L.periodic[a]:  # padded index: faces 0 .. n-1 at 1 .. n
                    j[a] = (j[a] - 1) % n[a] + 1
                if tuple(j) in idx:
                    M[k, idx[tuple(j)]] -= c[a]
    return M, K, B


def test_viscosity_operator_is_symmetric_positive_definite():
    s = scene(
        domain={
            "lower": [0, 0],
            "upper": [1, 1],
            "boundary": {"type": "sticky"},
            "faces": {
                "y+": {"type": "sticky", "velocity": [1.0, 0.0]},
                "x+": {"type": "open"},
                "x-": {"type": "slip"},
            },
        },
        colliders=[{"type": "Sphere", "center": [0.5, 0.4], "radius": 0.15}],
    )
    L = layout_of(s)
    for d in range(2):
        M, _, _ = _matrix(L, d)
        assert np.allclose(M, M.T) and np.linalg.eigvalsh(M).min() > 0
    # the lid: u faces just below it carry 2 c u_lid in B
    _, _, B = _matrix(L, 0)
    c = 1 / L.dx[1] ** 2
    assert np.allclose(B[2:8, 8], 2 * c * 1.0)
    p = layout_of(scene(domain={"lower": [0, 0], "upper": [1, 1], "boundary": {"type": "periodic"}}))
    M, _, _ = _matrix(p, 0)
    assert np.allclose(M.sum(axis=1), 0.0)  # periodic: constants are in the null space of the Laplacian part


def test_grid_measures_of_steadiness_and_drift(tmp_path):
    """grid_change_rate (run-to-steady-state check) and grid_field_drift (a state at rest keeps its
    smoke) on a hand-made grid file: a velocity relaxing towards a fixed field, smoke moving by 0.1."""
    import h5py

    from simcli.verify.measure import run_measurement

    t = np.array([0.0, 0.5, 1.0, 1.5])
    base = np.zeros((4, 3, 2))
    base[1, 2, 0] = 1.0
    vel = np.stack([base * (1.0 - math.exp(-k)) for k in t])  # (frames, ny, nx, 2)
    dens = np.zeros((4, 4, 3))
    dens[:, 0, :] = 1.0
    dens[2:, 1, 1] = 0.1
    p = tmp_path / "sim.h5"
    with h5py.File(p, "w") as f:
        f["time"] = t
        g = f.create_group("entities/fluid")
        g.attrs.update(kind="grid", origin=[0.0, 0.0], spacing=[0.25, 0.25])
        g["velocity"] = vel
        g["density"] = dens
    tt, rate = run_measurement(p, "grid_change_rate", "fluid", None, {})
    assert np.allclose(tt, t[1:])
    assert np.allclose(rate, np.abs(np.diff(1.0 - np.exp(-t))) / 0.5)
    tt, drift = run_measurement(p, "grid_field_drift", "fluid", None, {"field": "density"})
    assert np.allclose(drift, [0.0, 0.0, 0.1, 0.1])
