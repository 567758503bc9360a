"""The mass level of the Archimedes measures (simcli.verify.rigid_measures: rigid_draft's and
draft_fraction's ``level: mass``): the liquid's depth above a body's bottom by the rest volume above it."""

import numpy as np
import pytest

from simcli.verify.rigid_measures import _mass_level


def _tank(h=0.005, width=0.4, depth=0.12):
    xs = (np.arange(round(width / h)) + 0.5) * h
    ys = (np.arange(round(depth / h)) + 0.5) * h
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([X.ravel(), Y.ravel()], axis=1)


def test_mass_level_of_a_lattice_is_its_depth():
    h = 0.005
    x = _tank(h)
    far = np.abs(x[:, 0] - 0.2) > 0.06
    for y_ref in (0.1, 0.1012, 0.0973):  # on, between and off the lattice's layers
        d = _mass_level(x, far, 1, y_ref, h, h * h, 0.4 - 0.12)
        assert d == pytest.approx(0.12 - y_ref, abs=1e-12)


def test_mass_level_ignores_how_the_surface_layer_packs():
    """A surface layer sunk 0.15 spacing into the next (SPH's deficient top layer) leaves the mass above the
    body's bottom, hence the hydrostatic pressure there, unchanged; top + half a spacing moves with it."""
    h = 0.005
    x = _tank(h)
    top = x[:, 1] > 0.12 - h
    x[top, 1] -= 0.15 * h
    far = np.abs(x[:, 0] - 0.2) > 0.06
    assert _mass_level(x, far, 1, 0.1, h, h * h, 0.28) == pytest.approx(0.02, abs=1e-12)
    assert x[far, 1].max() + 0.5 * h == pytest.approx(0.12 - 0.15 * h)


def _h5(tmp_path, body, liquid, cells):
    """A sim.h5 with one frame of a floating body and a liquid (the layout simcli.io.hdf5 writes)."""
    import h5py

    path = tmp_path / "sim.h5"
    with h5py.File(path, "w") as f:
        f["time"] = np.array([0.0])
        for name, x in (("body", body), ("liquid", liquid)):
            g = f.create_group(f"entities/{name}")
            g["position"] = x[None]
        if cells:
            f["entities/body/cells"] = np.zeros((1, 4), np.int64)
    return h5py.File(path, "r")


def test_a_mesh_body_is_measured_from_its_vertices_a_particle_body_half_a_spacing_beyond(tmp_path):
    """draft_fraction: an FEM (mesh) body's vertices lie on its surface, so its bottom and top are its lowest
    and highest vertices; a particle body's outer particles sit half a spacing inside its surface. The same
    points read as a mesh (cells) and as particles: a box 0.04 high from 0.05 to 0.09 in a liquid whose
    columns' top particles stand at 0.055 (level 0.06): draft 0.25 as a mesh; as particles the box is taken
    as 0.045 to 0.095, draft 0.015 / 0.05."""
    from simcli.verify.coupling_measures import draft_fraction

    zs = np.array([0.05, 0.06, 0.07, 0.08, 0.09])
    X, Z = np.meshgrid(np.array([0.45, 0.5, 0.55]), zs, indexing="ij")
    body = np.stack([X.ravel(), Z.ravel()], axis=1)
    lx = (np.arange(100) + 0.5) * 0.01
    LX, LZ = np.meshgrid(lx, (np.arange(6) + 0.5) * 0.01, indexing="ij")
    liquid = np.stack([LX.ravel(), LZ.ravel()], axis=1)
    liquid = liquid[np.abs(liquid[:, 0] - 0.5) > 0.1]
    with _h5(tmp_path, body, liquid, cells=True) as f:
        _, d = draft_fraction(f, "body", "liquid", spacing=0.01, margin=0.02)
    assert d[0] == pytest.approx(0.25, abs=1e-9)
    (tmp_path / "sim.h5").unlink()
    with _h5(tmp_path, body, liquid, cells=False) as f:
        _, d = draft_fraction(f, "body", "liquid", spacing=0.01, margin=0.02)
    assert d[0] == pytest.approx(0.015 / 0.05, abs=1e-9)
