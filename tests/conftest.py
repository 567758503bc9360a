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


@pytest.fixture(scope="module", autouse=True)
def _fresh_taichi_per_module():
    """Each test module starts on a fresh Taichi runtime, as each `simcli run` does (one process): a worker
    process runs hundreds of tests, and Taichi's SNode numbering only restarts at a reset. Past 1024
    SNodes a sparse tree (the particle contact's grid) writes beyond the LLVM runtime's per-SNode arrays
    (simcli.backend.reset_taichi); in CI a worker later died with SIGSEGV in an unrelated test. The
    runtime is started again with the same settings (CPU, precision, threads); kernels come back from the
    offline cache."""
    from simcli import backend

    if backend._STATE:
        prev = backend.reset_taichi()
        arch = prev.get("arch")
        backend.init_taichi(
            "cpu" if arch in ("x64", "arm64") else "auto", prev.get("precision", "f32"), prev.get("threads")
        )
    yield


@pytest.fixture(scope="session")
def ti_f32():
    """Initialise Taichi on the CPU with f32 (once per session) and return its facts."""
    from simcli.backend import init_taichi

    info = init_taichi("cpu", "f32")
    if info.get("precision") != "f32":  # pragma: no cover - someone initialised f64 first
        pytest.skip("Taichi already initialised with f64 in this process")
    return info
