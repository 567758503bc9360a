"""`simcli info`: versions, backends and devices, exit 0, on a machine without a display or GPU.

Taichi's OpenGL probe (`_ti_core.with_opengl()`) killed `simcli info` with SIGSEGV (exit 139) on a
headless machine; the GPU backends are now asked in a child process, one crash costing one answer.
"""

import json
import os
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from simcli.backend import PROBED_BACKENDS, probe_backends

ROOT = Path(__file__).resolve().parents[2]


def _simcli(*args):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
        env=env,
    )


def test_info_json():
    r = _simcli("info", "--json")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    facts = json.loads(r.stdout)  # stdout is the JSON and nothing else
    assert facts["simcli"]
    assert facts["taichi"] == metadata.version("taichi")
    assert facts["numpy"] == metadata.version("numpy")
    assert facts["h5py"] == metadata.version("h5py")
    backends = facts["taichi_backends_compiled"]
    assert set(backends) == set(PROBED_BACKENDS)
    assert all(isinstance(v, bool) for v in backends.values()), backends
    assert isinstance(facts["cuda_driver"], bool)
    assert isinstance(facts["gpus"], list)
    assert facts["backend_auto"] in ("cpu", "cuda")
    if not (backends["cuda"] and facts["cuda_driver"]):
        assert facts["backend_auto"] == "cpu"
    assert facts["cpu_cores"] == len(os.sched_getaffinity(0))
    assert facts["memory_gb"] > 0


def test_info_text_goes_to_stderr():
    r = _simcli("info")
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""  # stdout is for machine-readable output only
    assert "Traceback" not in r.stderr
    lines = dict(line.split(": ", 1) for line in r.stderr.splitlines() if ": " in line)
    assert lines["taichi"] == metadata.version("taichi")
    assert set(lines) >= {"simcli", "python", "taichi_backends_compiled", "gpus", "backend_auto", "cpu_cores"}
    for name in PROBED_BACKENDS:
        assert f"{name}: " in lines["taichi_backends_compiled"]
    assert "[Taichi]" not in r.stderr  # no banner


def test_a_probe_that_crashes_costs_only_its_own_answer(tmp_path):
    """A child that dies with SIGSEGV in the middle (as Taichi's OpenGL probe does headless)."""
    fake = tmp_path / "fake_python"
    fake.write_text(
        "#!" + sys.executable + "\n"
        "import json, os, signal, sys\n"
        "names = sys.argv[3:]  # argv: -c CODE names...\n"
        "for n in names:\n"
        "    print(n, flush=True)\n"
        "    if n == 'opengl':\n"
        "        os.kill(os.getpid(), signal.SIGSEGV)\n"
        "    if n == 'slow':\n"
        "        import time; time.sleep(60)\n"
        "    print(json.dumps({n: n == 'cuda'}), flush=True)\n"
    )
    fake.chmod(0o755)
    got = probe_backends(("cuda", "opengl", "vulkan", "slow", "metal"), timeout_s=3, python=str(fake))
    assert got == {
        "cuda": True,
        "opengl": "probe failed: crashed (SIGSEGV)",
        "vulkan": False,
        "slow": "probe failed: timed out after 3 s",
        "metal": False,
    }
