"""Shared fixtures.

Taichi is initialised once per test process (its default float type cannot change
afterwards): in-process solver tests use f32 on the CPU through ``ti_f32``; f64 checks run in
a subprocess.
"""

import os

import pytest

# Taichi's offline kernel cache (simcli.backend: SIMCLI_KERNEL_CACHE, else ~/.cache/simcli/taichi) keeps at
# most 100 MB by default and trims a quarter of it, least recently used first, whenever a process ends above
# that. The shared cache sat at its cap (95 MB, with every `simcli run` on the machine writing to it) and the
# default suite found little of its own there: the FEM patch fixture, its code unchanged since the last
# full run, recompiled from scratch (52.9 s CPU; 11 s with its kernels cached). The suite keeps its own
# cache with room for all of its kernels; the variables are inherited by the `simcli run` subprocesses,
# and either can be set from outside. A cached kernel is the same compiled code (the key hashes the
# kernel and the compile settings), so no result changes. A fresh machine (CI without a kept ~/.cache)
# compiles everything once, as before.
_cache_home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
os.environ.setdefault("SIMCLI_KERNEL_CACHE", os.path.join(_cache_home, "simcli", "taichi-tests"))
os.environ.setdefault("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", str(1 << 30))  # 1 GiB (a C int; default 100 MB)


@pytest.fixture(scope="session")
def ti_f32():
    """Initialise Taichi on the CPU with f32 (once per session) and return its facts."""
    from simcli.backend import init_taichi

    info = init_taichi("cpu", "f32")
    if info.get("precision") != "f32":  # pragma: no cover - someone initialised f64 first
        pytest.skip("Taichi already initialised with f64 in this process")
    return info
