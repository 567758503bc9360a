"""tools/buchner_wall_profile.py's free-streamline wall pressure (docs/VALIDATION.md, Buchner audit): the
corner flow of a layer d deep at speed U, as half of a plane jet 2d wide impinging on a plate (Kirchhoff)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location(
    "buchner_wall_profile", Path(__file__).resolve().parents[2] / "tools" / "buchner_wall_profile.py"
)
bwp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bwp)


def test_stagnation_and_half_pressure_height():
    d, u = 0.05, 3.0
    p0 = 0.5 * 1000.0 * u * u
    assert bwp.jet_wall_pressure(0.0, d, u) == pytest.approx(p0, rel=1e-9)
    # q = 1/sqrt(2) (half the stagnation pressure) sits at y = (4 d / pi)(artanh q + arctan q) = 1.905 d
    q = 1.0 / np.sqrt(2.0)
    y = 4.0 * d / np.pi * (np.arctanh(q) + np.arctan(q))
    assert y / d == pytest.approx(1.905, abs=1e-3)
    assert bwp.jet_wall_pressure(y, d, u) == pytest.approx(0.5 * p0, rel=1e-9)


def test_falls_with_height_and_scales_with_depth():
    p = [bwp.jet_wall_pressure(y, 0.05, 3.0) for y in (0.02, 0.06, 0.10, 0.16, 0.30)]
    assert all(a > b for a, b in zip(p, p[1:]))
    # self-similar in y / d
    assert bwp.jet_wall_pressure(0.16, 0.08, 3.0) == pytest.approx(bwp.jet_wall_pressure(0.08, 0.04, 3.0))
    assert bwp.jet_wall_pressure(0.1, 0.0, 3.0) == 0.0


def test_wall_force_is_the_layers_momentum_flux():
    # the wall turns the layer's whole horizontal momentum flux rho U^2 d: int_0^inf p dy = rho U^2 d
    d, u = 0.06, 3.5
    y = np.concatenate([np.linspace(0.0, 0.5, 2001), np.linspace(0.5, 40.0 * d, 201)[1:]])
    p = np.array([bwp.jet_wall_pressure(a, d, u) for a in y])
    assert np.trapezoid(p, y) == pytest.approx(1000.0 * u * u * d, rel=2e-3)
