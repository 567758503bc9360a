"""Faults of `simcli run` end to end (issue 24): one run per output folder, no silent overwrite, write
failures (file-size limit, sim.h5 deleted under the run), what --resume refuses, signals during start-up,
and a SIGKILL at a random moment followed by repair and a bit-for-bit resume."""

from __future__ import annotations

import json
import os
import random
import resource
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

SCENE = """\
version: 1
name: tiny
sim: {dim: 2, dt: 4.0e-3, substeps: 8, steps: 20, threads: 1}
domain: {lower: [0.0, 0.0], upper: [1.0, 1.0], boundary: {type: slip, friction: 0.2}}
solvers: {mpm: {grid_density: 32}}
entities:
  - name: blob
    material: {type: MPM.Elastic, E: 2.0e4, nu: 0.3, rho: 1000, model: neohooken}
    morph: {type: Box, lower: [0.4, 0.3], upper: [0.6, 0.5]}
    velocity: [0.5, 0.0]
output: {every: 2, formats: [hdf5, vtk]}
checkpoint: {every: 10, keep: 2}
"""
LONG = SCENE.replace("steps: 20", "steps: 100000").replace("every: 2,", "every: 1,")


def _scene(tmp_path: Path, text: str = SCENE, name: str = "scene.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _run(args, timeout=300, **kw):
    return subprocess.run(
        [sys.executable, "-m", "simcli", *args], capture_output=True, text=True, timeout=timeout, **kw
    )


def _popen(args, **kw):
    return subprocess.Popen(
        [sys.executable, "-m", "simcli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def _frames(h5: Path) -> int:
    try:
        with h5py.File(h5, "r", swmr=True) as f:
            return len(f["time"])
    except (OSError, KeyError):
        return 0


def _wait_for(cond, proc, timeout=180.0, every=0.02):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if cond():
            return
        if proc.poll() is not None:
            raise AssertionError(f"run ended early: {proc.returncode} {proc.stderr.read()}")
        time.sleep(every)
    raise AssertionError("timed out")


def _rj(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())


def _pvd_ok(out: Path, entity: str = "blob") -> list[str]:
    """The .pvd lists only files that exist; returns them."""
    listed = [d.get("file") for d in ET.parse(out / "vtk" / f"{entity}.pvd").getroot().iter("DataSet")]
    missing = [f for f in listed if not (out / "vtk" / f).is_file()]
    assert not missing, missing
    return listed


# -- one run per folder, no silent overwrite ----------------------------------------------------------


def test_a_second_run_into_a_locked_folder_is_exit_74_and_leaves_it_alone(tmp_path):
    from simcli.io.outdir import OutputLock

    out = tmp_path / "out"
    out.mkdir()
    (out / "run.json").write_text('{"status": "running"}')
    with OutputLock(out, "the first run"):
        r = _run(["run", str(_scene(tmp_path)), "-o", str(out), "-q"])
    assert r.returncode == 74, r.stderr
    assert f"in use by pid {os.getpid()}" in r.stderr and "one run writes a folder at a time" in r.stderr
    assert "Traceback" not in r.stderr
    assert _rj(out) == {"status": "running"}  # the first run's run.json untouched
    assert not (out / "sim.h5").exists()


def test_a_finished_folder_needs_overwrite_or_resume(tmp_path):
    scene = _scene(tmp_path, SCENE.replace("steps: 20", "steps: 4"))
    out = tmp_path / "out"
    assert _run(["run", str(scene), "-o", str(out), "-q"]).returncode == 0
    info = _rj(out)
    assert info["lock"]["pid"] == info["pid"] and info["lock"]["host"] == info["host"]
    mtime = (out / "sim.h5").stat().st_mtime_ns
    r = _run(["run", str(scene), "-o", str(out), "-q"])
    assert r.returncode == 2, r.stderr
    assert "holds a previous run" in r.stderr and "--overwrite" in r.stderr and "--resume" in r.stderr
    assert (out / "sim.h5").stat().st_mtime_ns == mtime and _rj(out) == info
    r = _run(["run", str(scene), "-o", str(out), "-q", "--overwrite", "--resume"])
    assert r.returncode == 2 and "give one" in r.stderr
    # --overwrite replaces it: nothing of the previous run survives (a stale checkpoint would be resumed
    # later)
    stale = out / "checkpoints" / "ckpt_00000099.npz"
    stale.parent.mkdir(exist_ok=True)
    stale.write_bytes(b"old")
    r = _run(["run", str(scene), "-o", str(out), "-q", "--overwrite"])
    assert r.returncode == 0, r.stderr
    assert not stale.exists() and _rj(out)["status"] == "done" and _rj(out)["pid"] != info["pid"]
    with h5py.File(out / "sim.h5", "r") as f:
        assert list(f["step"][...]) == [0, 2, 4]


# -- write failures ---------------------------------------------------------------------------------


def _fsize_limit():  # pragma: no cover - runs in the child
    resource.setrlimit(resource.RLIMIT_FSIZE, (150_000, 150_000))


def test_file_size_limit_is_exit_74_with_every_completed_frame(tmp_path):
    out = tmp_path / "out"
    text = LONG.replace("steps: 100000", "steps: 200").replace("{every: 10, keep: 2}", "{every: 20, keep: 2}")
    scene = _scene(tmp_path, text)
    r = _run(["run", str(scene), "-o", str(out), "-q"], preexec_fn=_fsize_limit)
    assert r.returncode == 74, (r.returncode, r.stderr[-3000:])  # was a SIGSEGV / SIGBUS at exit
    assert "Traceback" not in r.stderr and "sim.h5" in r.stderr and "file-size limit" in r.stderr
    info = _rj(out)
    assert info["status"] == "failed" and info["exit_code"] == 74
    rr = _run(["repair", str(out)])
    assert rr.returncode == 0, rr.stderr
    n = int(rr.stderr.split("; ")[-1].split(" frames readable")[0])
    assert n >= 5
    with h5py.File(out / "sim.h5", "r") as f:
        assert len(f["time"]) == n
        x = f["entities/blob/position"][:n]
        assert np.isfinite(x).all() and list(f["step"][:n]) == list(range(n))
    assert len(_pvd_ok(out)) >= n
    # with room again, --resume continues from the newest checkpoint to the end
    r = _run(["run", str(scene), "-o", str(out), "-q", "--resume"])
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        assert list(f["step"][...]) == list(range(201))
    assert len(_pvd_ok(out)) == 201


def test_sim_h5_deleted_while_running_is_exit_74_and_written_back(tmp_path):
    out = tmp_path / "out"
    p = _popen(["run", str(_scene(tmp_path, LONG)), "-o", str(out), "-q"])
    try:
        _wait_for(lambda: _frames(out / "sim.h5") >= 4, p)
        os.unlink(out / "sim.h5")
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 74, err  # was exit 0, "done", with no sim.h5
    assert "was deleted by another process" in err and "written back" in err and "Traceback" not in err
    assert _rj(out)["status"] == "failed"
    r = _run(["repair", str(out)])
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        n = len(f["time"])
        assert n >= 4 and np.isfinite(f["entities/blob/position"][:n]).all()


# -- what --resume refuses ----------------------------------------------------------------------------


def test_resume_refuses_a_changed_physics_or_time_axis_and_edited_metadata(tmp_path):
    from simcli.io import read_checkpoint, write_checkpoint

    scene = _scene(tmp_path)
    out = tmp_path / "out"
    assert _run(["run", str(scene), "-o", str(out), "-q"]).returncode == 0
    before = _rj(out)
    for sets, key in [
        (["sim.dt=1.0e-3"], "sim.dt: 0.004 in the checkpoint, 0.001 now"),
        (["entities.0.material.E=3.0e4"], "entities.0.material.E"),
        (["sim.gravity=[0, -1]"], "sim.gravity"),
        (["output.every=1"], "output.every"),
        (["sim.precision=f64", "sim.substeps=4"], "sim.substeps"),
    ]:
        args = ["run", str(scene), "-o", str(out), "-q", "--resume"]
        for s in sets:
            args += ["--set", s]
        r = _run(args)
        assert r.returncode == 65, (sets, r.stderr)
        assert key in r.stderr and "does not fit this scene" in r.stderr and "Traceback" not in r.stderr
    assert "sim.precision" in r.stderr  # every key that differs is named
    assert _rj(out) == before  # a refused resume leaves the run as it was

    (ck,) = sorted((out / "checkpoints").glob("ckpt_*.npz"))
    state, meta = read_checkpoint(ck)
    meta["step"] = -10
    ck.unlink()
    write_checkpoint(out / "checkpoints", 10, state, meta, keep=2)
    r = _run(["run", str(scene), "-o", str(out), "-q", "--resume"])
    assert r.returncode == 65, r.stderr
    assert "inconsistent metadata" in r.stderr and "step = -10" in r.stderr and "Traceback" not in r.stderr


# -- signals during start-up --------------------------------------------------------------------------


def test_a_signal_before_the_run_starts_is_honoured_in_process(tmp_path):
    """The handlers `simcli run` installs first record a signal that arrives while the scene loads; the
    runner stops at its first start-up phase: run.json says interrupted, exit 75, nothing to resume."""
    from simcli.runner import run_scene
    from simcli.runsignals import RunSignals
    from simcli.scene.loader import load_scene

    sig = RunSignals()
    sig.received = "SIGTERM"
    out = tmp_path / "out"
    code, info = run_scene(load_scene(_scene(tmp_path)), out_dir=out, quiet=True, signals=sig)
    assert code == 75 and info["status"] == "interrupted"
    assert _rj(out)["status"] == "interrupted" and "nothing to resume yet" in _rj(out)["error"]
    assert not (out / "sim.h5").exists() and not (out / "checkpoints").exists()


def _catches_sigterm(pid: int) -> bool:
    """Whether process ``pid`` has a handler for SIGTERM (Linux: SigCgt in /proc/<pid>/status)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    except OSError:
        pass
    return False


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_sigterm_as_soon_as_it_is_caught_is_exit_75_with_run_json(tmp_path):
    """SIGTERM the moment `simcli run` has a handler for it (while it still loads the scene, long before
    Taichi): honoured, not fatal; run.json says interrupted."""
    out = tmp_path / "out"
    p = _popen(["run", str(_scene(tmp_path)), "-o", str(out)])
    try:
        _wait_for(lambda: _catches_sigterm(p.pid), p, every=0.001)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 75, err
    assert "received during start-up" in err and "nothing to resume yet" in err and "Traceback" not in err
    assert _rj(out)["status"] == "interrupted" and not (out / "sim.h5").exists()


def test_sigterm_while_taichi_starts_is_exit_75_with_run_json(tmp_path):
    out = tmp_path / "out"
    p = _popen(["run", str(_scene(tmp_path)), "-o", str(out)])

    def starting():
        try:
            return _rj(out).get("status") == "starting"
        except (OSError, ValueError):
            return False

    try:
        _wait_for(starting, p, every=0.005)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 75, err
    assert "received during start-up" in err and "nothing to resume yet" in err
    info = _rj(out)
    assert info["status"] == "interrupted" and info["exit_code"] == 75
    assert not list((out / "checkpoints").glob("*.npz")) if (out / "checkpoints").exists() else True
    # nothing was written that needs --overwrite: the same command starts afresh
    r = _run(["run", str(_scene(tmp_path, SCENE.replace("steps: 20", "steps: 2"))), "-o", str(out), "-q"])
    assert r.returncode == 0, r.stderr


# -- SIGKILL at a random moment, repair, resume bit for bit -------------------------------------------

KILL = (
    SCENE.replace("steps: 20", "steps: 160")
    .replace("checkpoint: {every: 10, keep: 2}", "checkpoint: {every: 16, keep: 3}")
    .replace("grid_density: 32", "grid_density: 64")
    .replace("upper: [0.6, 0.5]}", "upper: [0.7, 0.6]}")
)


def test_sigkill_at_a_random_moment_then_repair_and_resume_equal_an_uninterrupted_run(tmp_path):
    seed = int(os.environ.get("SIMCLI_KILL_SEED", "24"))
    rng = random.Random(seed)
    scene = _scene(tmp_path, KILL)
    ref = tmp_path / "ref"
    r = _run(["run", str(scene), "-o", str(ref), "-q"])
    assert r.returncode == 0, r.stderr
    with h5py.File(ref / "sim.h5", "r") as f:
        n_ref = len(f["time"])
        want = {k: f[f"entities/blob/{k}"][...] for k in f["entities/blob"] if k != "cells"}
        t_ref, s_ref = f["time"][...], f["step"][...]

    out = tmp_path / "out"
    target = rng.randint(3, int(n_ref * 0.7))  # frames written before the kill
    extra = rng.uniform(0.0, 0.05)
    p = _popen(["run", str(scene), "-o", str(out), "-q"])
    try:
        _wait_for(lambda: _frames(out / "sim.h5") >= target, p, every=0.01)
        time.sleep(extra)
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == -signal.SIGKILL, f"seed {seed}: the run ended before the kill ({p.returncode})"

    r = _run(["repair", str(out)])
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "sim.h5", "r") as f:  # a plain open: what ParaView does
        n = len(f["time"])
        assert target <= n < n_ref, (seed, target, n)
        np.testing.assert_array_equal(f["time"][...], t_ref[:n])
        for k, a in want.items():  # every completed frame, bit for bit the uninterrupted run's
            np.testing.assert_array_equal(f[f"entities/blob/{k}"][:n], a[:n], err_msg=f"seed {seed}: {k}")
    listed = _pvd_ok(out)
    assert len(listed) >= 1

    r = _run(["run", str(scene), "-o", str(out), "-q", "--resume"])
    if not list((out / "checkpoints").glob("ckpt_*.npz")):
        # killed before the first checkpoint: nothing to resume, say so; starting again needs --overwrite
        assert r.returncode == 2 and "no checkpoint" in r.stderr, r.stderr
        r = _run(["run", str(scene), "-o", str(out), "-q", "--overwrite"])
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        np.testing.assert_array_equal(f["time"][...], t_ref)
        np.testing.assert_array_equal(f["step"][...], s_ref)
        for k, a in want.items():
            np.testing.assert_array_equal(f[f"entities/blob/{k}"][...], a, err_msg=f"seed {seed}: {k}")
    assert len(_pvd_ok(out)) == n_ref
