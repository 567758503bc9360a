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
