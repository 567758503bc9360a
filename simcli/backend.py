"""Taichi initialisation: the only place that imports Taichi for the first time.

Taichi prints banners on stdout; stdout is reserved for machine-readable output, so
the import and ``ti.init`` run with file descriptor 1 pointed at stderr.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time

_STATE: dict = {}


@contextlib.contextmanager
def stdout_to_stderr():
    """Send everything written to fd 1 (Python and C level) to fd 2 for the duration."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def default_cache_dir() -> str:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "simcli", "taichi")


def _has_gpu_driver() -> bool:
    """Whether a CUDA driver library can be loaded (Taichi's own probe prints warnings)."""
    import ctypes.util

    if ctypes.util.find_library("cuda"):
        return True
    for p in (
        "/usr/lib/x86_64-linux-gnu/libcuda.so.1",
        "/usr/lib64/libcuda.so.1",
        "/usr/lib/wsl/lib/libcuda.so.1",
    ):
        if os.path.exists(p):
            return True
    return sys.platform == "darwin"  # Metal


def platform_hint(backend: str) -> str:
    if backend in ("cuda", "gpu") and not _has_gpu_driver():
        return "no CUDA driver library (libcuda) found"
    return f"Taichi found no usable {backend} device"


def init_taichi(
    backend: str = "cpu", precision: str = "f32", threads: int | None = None, debug: bool = False
) -> dict:
    """Initialise Taichi once per process and return facts about it.

    backend: auto | cpu | gpu | cuda | vulkan | metal. ``auto`` tries a GPU and falls back
    to the CPU. Returns {'arch', 'import_s', 'init_s', 'threads', 'cache'}.
    """
    if _STATE:
        return dict(_STATE)
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")  # the version banner
    t0 = time.perf_counter()
    with stdout_to_stderr():
        import taichi as ti
    import_s = time.perf_counter() - t0

    arch_map = {
        "cpu": ti.cpu,
        "gpu": ti.gpu,
        "cuda": ti.cuda,
        "vulkan": ti.vulkan,
        "metal": ti.metal,
        "auto": ti.gpu,
    }
    if backend == "auto" and not _has_gpu_driver():
        backend = "cpu"
    elif backend in ("cuda", "gpu") and not _has_gpu_driver():
        from simcli.errors import SimcliError

        raise SimcliError(
            f"backend '{backend}' requested but not available on this machine ({platform_hint(backend)}). "
            f"Use --backend auto (a GPU if present, else the CPU) or --backend cpu"
        )
    fp = ti.f64 if precision == "f64" else ti.f32
    cache = os.environ.get("SIMCLI_KERNEL_CACHE", default_cache_dir())
    kwargs = dict(
        default_fp=fp,
        default_ip=ti.i32,
        offline_cache=True,
        offline_cache_file_path=cache,
        log_level=ti.WARN,
        random_seed=0,
        debug=debug,
    )
    if threads is None:
        env = os.environ.get("SLURM_CPUS_PER_TASK") or os.environ.get("SIMCLI_THREADS")
        if env:
            threads = int(env)
        else:
            try:
                threads = len(os.sched_getaffinity(0))
            except AttributeError:  # pragma: no cover - non-Linux
                threads = os.cpu_count() or 1
    # never more threads than the cores this process may use (sim.threads: 100000 once started ~32,000 threads
    # and hit the machine's thread limit): clamped, and `simcli validate` / `run` warn (docs/LIMITS.md)
    from simcli.scene.limits import allowed_threads

    threads = max(1, min(int(threads), allowed_threads()))
    t0 = time.perf_counter()
    with stdout_to_stderr():
        if backend == "cpu":
            ti.init(arch=ti.cpu, cpu_max_num_threads=threads, **kwargs)
        else:
            ti.init(arch=arch_map[backend], cpu_max_num_threads=threads, **kwargs)
    init_s = time.perf_counter() - t0
    arch = ti.lang.impl.current_cfg().arch
    arch_name = str(arch).split(".")[-1]
    if backend not in ("auto", "cpu") and arch_name in ("x64", "arm64"):
        # Taichi falls back to the CPU when the requested arch is missing. A batch job that asked
        # for a GPU must not run for hours on the CPU instead: stop and say so.
        from simcli.errors import SimcliError

        raise SimcliError(
            f"backend '{backend}' requested but not available on this machine ({platform_hint(backend)}); "
            f"Taichi would fall back to the CPU. Use --backend auto (a GPU if present, else the CPU) "
            f"or --backend cpu"
        )
    _STATE.update(
        arch=arch_name,
        import_s=import_s,
        init_s=init_s,
        threads=threads if arch_name == "x64" or arch_name == "arm64" else None,
        cache=cache,
        precision=precision,
        taichi=ti.__version__,
    )
    return dict(_STATE)
