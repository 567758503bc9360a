"""Shared fixtures.

Taichi is initialised once per test process (its default float type cannot change
afterwards): in-process solver tests use f32 on the CPU through ``ti_f32``; f64 checks run in
a subprocess.
"""

import pytest


@pytest.fixture(scope="session")
def ti_f32():
    """Initialise Taichi on the CPU with f32 (once per session) and return its facts."""
    from simcli.backend import init_taichi

    info = init_taichi("cpu", "f32")
    if info.get("precision") != "f32":  # pragma: no cover - someone initialised f64 first
        pytest.skip("Taichi already initialised with f64 in this process")
    return info
