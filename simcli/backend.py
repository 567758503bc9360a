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

# Taichi prints a version banner ("[Taichi] version 1.7.4, llvm ...") when it is first imported,
# whichever module does it; simcli reports the version in run.json and `simcli info` instead.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")


@contextlib.contextmanager
def stdout_to(fd: int):
    """Send everything written to fd 1 (Python and C level) to ``fd`` for the duration."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(fd, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def stdout_to_stderr():
    """Send everything written to fd 1 (Python and C level) to fd 2 for the duration."""
    return stdout_to(2)


@contextlib.contextmanager
def quiet_stdout(quiet: bool):
    """Taichi's own lines on fd 1 ("[Taichi] Starting on arch=x64"): to stderr, or nowhere when quiet."""
    if not quiet:
        with stdout_to(2):
            yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        with stdout_to(null):
            yield
    finally:
        os.close(null)


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
    backend: str = "cpu",
    precision: str = "f32",
    threads: int | None = None,
    debug: bool = False,
    quiet: bool = False,
) -> dict:
    """Initialise Taichi once per process and return facts about it.

    backend: auto | cpu | gpu | cuda | vulkan | metal. ``auto`` tries a GPU and falls back
    to the CPU. ``quiet``: nothing of Taichi's own on the terminal (its banner and "Starting
    on arch" line; its warnings and errors still go to stderr). Returns {'arch', 'import_s', 'init_s',
    'threads', 'cache'}.
    """
    if _STATE:
        return dict(_STATE)
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")  # the version banner
    t0 = time.perf_counter()
    with quiet_stdout(quiet):
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
    if "TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES" not in os.environ:
        # Taichi's default cap is 100 MB, trimmed by a quarter (least recently used) whenever a process ends
        # above it: one family's kernels are 20-50 MB, so a user running scenes of three families found their
        # kernels recompiled (5-50 s each start-up). 512 MiB keeps them all; the variable overrides it.
        kwargs["offline_cache_max_size_of_files"] = 512 * 1024 * 1024
    if threads is None:
        env = os.environ.get("SLURM_CPUS_PER_TASK") or os.environ.get("SIMCLI_THREADS")
        env_threads = None
        if env:
            try:
                env_threads = int(env)
            except ValueError:  # a malformed variable is ignored with a word, never a traceback
                print(
                    f"simcli: warning: SLURM_CPUS_PER_TASK / SIMCLI_THREADS = {env!r} is not a whole number; "
                    "using the cores this process may use",
                    file=sys.stderr,
                )
        if env_threads is not None:
            threads = env_threads
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
    with quiet_stdout(quiet):
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


#: Taichi's ``taichi_max_num_snodes``: its LLVM runtime's per-SNode arrays (indexed by the process-wide SNode
#: id) have this many entries; a sparse tree must be numbered below it (``reset_taichi``)
MAX_SNODES = 1024


def next_snode_id() -> int:
    """The id Taichi gives the next SNode in this process (0 before any field is materialised)."""
    from taichi.lang import impl

    prog = impl.get_runtime().prog
    if prog is None:
        return 0
    top = -1
    stack = [prog.get_snode_root(i) for i in range(prog.get_snode_tree_size())]
    pending = getattr(getattr(impl, "_root_fb", None), "ptr", None)  # fields declared, not yet materialised
    if pending is not None:
        stack.append(pending)
    while stack:
        s = stack.pop()
        top = max(top, s.id)
        stack.extend(s.get_ch(i) for i in range(s.get_num_ch()))
    return top + 1


def reset_taichi() -> dict:
    """End this process's Taichi runtime (every field and compiled kernel; the offline cache is written)
    and return the facts it was started with ({} if it was not): ``init_taichi`` starts a fresh one.

    One `simcli run` is one process and never needs this. A process that builds scene after scene does
    (the test suite, one worker for hundreds of tests): Taichi numbers its SNodes with a counter that only
    a reset clears, and its LLVM runtime keeps per-SNode state in fixed arrays of 1024 entries
    (``taichi_max_num_snodes``) written without a bounds check; a sparse (pointer) tree built past that,
    as the particle contact's grid is, writes beyond them."""
    prev = dict(_STATE)
    if _STATE:
        import taichi as ti

        ti.reset()
        _STATE.clear()
    return prev


# ---------------------------------------------------------------------------------------------
# `simcli info`: what this machine offers, without risking the process that asks
# ---------------------------------------------------------------------------------------------

#: the GPU backends `--backend` offers, probed by `simcli info`. (Taichi's OpenGL probe,
#: ``_ti_core.with_opengl()``, is not among them: simcli does not offer OpenGL, and that probe
#: kills the process with SIGSEGV on a machine without a display.)
PROBED_BACKENDS = ("cuda", "vulkan", "metal")

_PROBE_CHILD = r"""
import json, os, sys
out = os.fdopen(os.dup(1), "w")
os.dup2(2, 1)  # Taichi's banners and warnings: not on our channel
os.environ["ENABLE_TAICHI_HEADER_PRINT"] = "False"
os.environ.setdefault("TI_LOG_LEVEL", "error")
from taichi._lib import core
for name in sys.argv[1:]:
    out.write(name + "\n")  # announced first: if the probe kills us, the parent knows which one
    out.flush()
    f = getattr(core, "with_" + name, None)
    out.write(json.dumps({name: bool(f()) if f is not None else None}) + "\n")
    out.flush()
"""


def probe_backends(names=PROBED_BACKENDS, timeout_s: float = 60.0, python: str | None = None) -> dict:
    """Which GPU backends this Taichi build has, each asked in a child process.

    Returns {name: True | False | None (this Taichi does not know it) | "probe failed: ..."}.
    A probe that crashes or hangs takes down only the child; the others are asked again in a
    fresh one. Never raises.
    """
    import json
    import subprocess

    result: dict = {}
    left = list(names)
    while left:
        try:
            r = subprocess.run(
                [python or sys.executable, "-c", _PROBE_CHILD, *left],
                capture_output=True,
                text=True,
                timeout=timeout_s,
            )
            lines, rc = r.stdout.splitlines(), r.returncode
        except subprocess.TimeoutExpired as e:
            out = e.stdout.decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
            lines, rc = out.splitlines(), None
        except OSError as e:  # pragma: no cover - no interpreter
            return {**result, **{n: f"probe failed: {e}" for n in left}}
        current = None
        for line in lines:
            if line.startswith("{"):
                result.update(json.loads(line))
                current = None
            else:
                current = line.strip()
        left = [n for n in left if n not in result]
        if not left:
            break
        if current is None:  # died before it asked anything (e.g. Taichi does not import)
            why = "timed out" if rc is None else f"exit {rc}"
            return {**result, **{n: f"probe failed: Taichi did not load ({why})" for n in left}}
        if rc is None:
            why = f"timed out after {timeout_s:g} s"
        elif rc < 0:
            import signal

            try:
                why = f"crashed ({signal.Signals(-rc).name})"
            except ValueError:
                why = f"crashed (signal {-rc})"
        else:
            why = f"exit {rc}"
        result[current] = f"probe failed: {why}"
        left.remove(current)
    return result


def machine_facts(timeout_s: float = 60.0) -> dict:
    """Versions, backends and devices for `simcli info` (importing Taichi only in a child)."""
    import platform
    import subprocess
    from importlib import metadata

    from simcli import __version__

    facts: dict = {
        "simcli": __version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
    }
    for dist in ("taichi", "numpy", "h5py", "meshio", "pydantic", "PyYAML", "click"):
        try:
            facts[dist.lower()] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            facts[dist.lower()] = None
    if facts["taichi"] is not None:
        facts["taichi_backends_compiled"] = probe_backends(timeout_s=timeout_s)
    else:
        facts["taichi_backends_compiled"] = {}
    facts["cuda_driver"] = _has_gpu_driver()
    try:
        r = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,memory.total", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        gpus = [g.strip() for g in r.stdout.splitlines() if g.strip()] if r.returncode == 0 else []
    except (OSError, subprocess.SubprocessError):
        gpus = []
    facts["gpus"] = gpus
    cuda_ok = facts["taichi_backends_compiled"].get("cuda") is True and facts["cuda_driver"]
    facts["backend_auto"] = "cuda" if cuda_ok else "cpu"
    facts["cpu"] = _cpu_model() or platform.processor() or platform.machine()
    try:
        facts["cpu_cores"] = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        facts["cpu_cores"] = os.cpu_count()
    facts["memory_gb"] = _memory_gb()
    return facts


def _cpu_model() -> str | None:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


def _memory_gb() -> float | None:
    try:
        return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return None
