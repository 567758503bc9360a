"""Faults of the output layer (issue 24), without Taichi: the output folder's lock, write failures
(file-size limit, sim.h5 deleted or truncated under the writer), `simcli repair` on what is not a
repairable sim.h5, and what --resume compares."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from simcli.cli import cli
from simcli.errors import OutputError
from simcli.io import EntityMeta, FrameSink
from simcli.io.outdir import LOCK_NAME, OutputBusy, OutputLock, previous_run
from simcli.resume_check import meta_problems, scene_differences

REPO = Path(__file__).resolve().parents[2]


def _ents(n=400):
    return [EntityMeta("blob", "particles", n, 3, {"position": (3, "m"), "velocity": (3, "m/s")})]


def _frame(fr, n=400):
    x = (fr * 1000 + np.arange(n * 3, dtype=np.float32).reshape(n, 3)) / 7.0
    return {"blob": {"position": x, "velocity": -x}}


def _write(out: Path, frames: int, close=True, formats=("hdf5",)) -> FrameSink:
    sink = FrameSink(out, list(formats))
    sink.open(_ents(), "version: 1\n", {"name": "t", "dt": 0.1, "dim": 3})
    for fr in range(frames):
        sink.write_frame(fr, fr, fr * 0.1, _frame(fr))
    if close:
        sink.close()
    return sink


def _repair(out: Path):
    r = CliRunner().invoke(cli, ["repair", str(out)])
    # a traceback would leave a non-SystemExit exception behind
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    return r


def _check_frames(h5: Path, n: int) -> None:
    with h5py.File(h5, "r") as f:
        assert len(f["time"]) == n
        for fr in range(n):
            np.testing.assert_array_equal(f["entities/blob/position"][fr], _frame(fr)["blob"]["position"])


# -- the lock --------------------------------------------------------------------------------------


def test_output_lock_is_exclusive_names_its_holder_and_dies_with_it(tmp_path):
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(
                f"""
                import sys, time
                from simcli.io.outdir import OutputLock
                OutputLock({str(tmp_path)!r}, "holder").acquire()
                print("locked", flush=True)
                time.sleep(120)
                """
            ),
        ],
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(OutputBusy, match=rf"in use by pid {holder.pid} on .*holder"):
            OutputLock(tmp_path).acquire()
        # repair waits for no one either: it refuses a folder a run is writing
        r = _repair(tmp_path)
        assert r.exit_code == 74 and "in use by" in r.output
        holder.send_signal(signal.SIGKILL)  # a killed holder leaves nothing stuck
        holder.wait(timeout=30)
    finally:
        if holder.poll() is None:
            holder.kill()
    with OutputLock(tmp_path) as lock:
        assert lock.info["pid"] == os.getpid()
        with pytest.raises(OutputBusy):  # flock is per open file: a second open in one process conflicts too
            OutputLock(tmp_path).acquire()
    OutputLock(tmp_path).acquire().release()
    assert (tmp_path / LOCK_NAME).exists()


def test_previous_run_counts_outputs_only(tmp_path):
    assert previous_run(tmp_path) is None
    (tmp_path / "run.json").write_text('{"status": "interrupted"}')
    (tmp_path / "notes.txt").write_text("mine")
    assert previous_run(tmp_path) is None  # a run that stopped before it wrote anything: nothing to lose
    _write(tmp_path, 2)
    assert "sim.h5" in previous_run(tmp_path) and "status 'interrupted'" in previous_run(tmp_path)


# -- write failures ---------------------------------------------------------------------------------


def test_file_size_limit_is_an_output_error_and_keeps_every_completed_frame(tmp_path):
    """Under `ulimit -f` a sim.h5 flush fails with EFBIG: an OutputError naming the file, a clean exit
    (HDF5 used to crash the process at exit: SIGSEGV/SIGBUS), and every completed frame after repair."""
    script = textwrap.dedent(
        f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_FSIZE, (150_000, 150_000))
        sys.path.insert(0, {str(REPO / "tests" / "unit")!r})
        from test_faults_io import _write
        from simcli.errors import OutputError
        try:
            _write(__import__("pathlib").Path({str(tmp_path)!r}), 1000, formats=("hdf5", "vtk"))
        except OutputError as e:
            print("ERROR", e, flush=True)
            sys.exit(74)
        sys.exit(0)
        """
    )
    r = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        timeout=120,
    )
    assert r.returncode == 74, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    msg = r.stdout
    assert "sim.h5" in msg and "file-size limit" in msg and "completed before are kept" in msg
    n = int(re.search(r"the (\d+) frame\(s\) completed", msg).group(1))
    assert n >= 3
    rr = _repair(tmp_path)
    assert rr.exit_code == 0 and f"{n} frames readable" in rr.output, rr.output
    _check_frames(tmp_path / "sim.h5", n)


def test_sim_h5_deleted_under_the_writer_is_detected_and_written_back(tmp_path):
    sink = _write(tmp_path, 3, close=False)
    os.unlink(tmp_path / "sim.h5")
    with pytest.raises(OutputError, match="was deleted by another process.*3 completed frame.*written back"):
        sink.write_frame(3, 3, 0.3, _frame(3))
    sink.abort()
    assert _repair(tmp_path).exit_code == 0
    _check_frames(tmp_path / "sim.h5", 3)


def test_sim_h5_truncated_under_the_writer_is_detected(tmp_path):
    sink = _write(tmp_path, 3, close=False)
    os.truncate(tmp_path / "sim.h5", 0)
    with pytest.raises(OutputError, match=r"was truncated by another process .* -> 0 bytes"):
        sink.write_frame(3, 3, 0.3, _frame(3))
    sink.abort()
    r = _repair(tmp_path)
    assert r.exit_code == 74 and "empty (0 bytes)" in r.output


def test_sim_h5_deleted_after_the_last_frame_fails_the_close(tmp_path):
    sink = _write(tmp_path, 2, close=False)
    os.unlink(tmp_path / "sim.h5")
    with pytest.raises(OutputError, match="was deleted"):
        sink.close()
    assert _repair(tmp_path).exit_code == 0
    _check_frames(tmp_path / "sim.h5", 2)


# -- repair ----------------------------------------------------------------------------------------


def _damage(tmp_path: Path, how: str) -> str:
    h5 = tmp_path / "sim.h5"
    if how == "missing":
        return "not found"
    if how == "empty":
        h5.write_bytes(b"")
        return "empty (0 bytes)"
    if how == "text":
        h5.write_text("this is not HDF5\n" * 10)
        return "not an HDF5 file"
    if how == "folder":
        h5.mkdir()
        return "is a folder"
    _write(tmp_path, 20)
    if how == "superblock":
        with open(h5, "r+b") as f:
            f.seek(20)
            b = f.read(1)
            f.seek(20)
            f.write(bytes([b[0] ^ 0xFF]))
        return "superblock damaged"
    if how == "truncated":
        os.truncate(h5, h5.stat().st_size // 2)
        return "sim.h5"
    raise AssertionError(how)


@pytest.mark.parametrize("how", ["missing", "empty", "text", "folder", "superblock", "truncated"])
def test_repair_on_what_is_not_a_repairable_sim_h5_is_exit_74(tmp_path, how):
    expect = _damage(tmp_path, how)
    r = _repair(tmp_path)
    assert r.exit_code == 74, r.output
    assert expect in r.output and "Traceback" not in r.output
    assert "frames readable" not in r.output  # never a count it did not verify


def test_repair_of_a_clean_file_reads_every_frame(tmp_path):
    _write(tmp_path, 5)
    r = _repair(tmp_path)
    assert r.exit_code == 0 and "already clean; 5 frames readable" in r.output
    r = _repair(tmp_path / "sim.h5")  # the file itself: its folder
    assert r.exit_code == 0 and "5 frames readable" in r.output
    r = _repair(tmp_path / "nowhere")
    assert r.exit_code == 74 and "no such folder" in r.output
    (tmp_path / "notes.txt").write_text("x")
    r = _repair(tmp_path / "notes.txt")
    assert r.exit_code == 74 and "not a folder" in r.output


# -- what --resume compares ------------------------------------------------------------------------

SCENE = {
    "version": 1,
    "name": "a",
    "sim": {"dim": 2, "dt": 0.004, "substeps": 8, "steps": 40, "threads": 1, "precision": "f32"},
    "solvers": {"mpm": {"grid_density": 32.0}, "sph": {"particle_size": 0.02}},
    "entities": [{"name": "blob", "material": {"type": "MPM.Elastic", "E": 2e4}, "velocity": [0.5, 0.0]}],
    "output": {"dir": "out/a", "every": 2, "formats": ["hdf5"]},
    "checkpoint": {"every": 10, "keep": 2},
}


def _changed(**kv):
    import copy

    s = copy.deepcopy(SCENE)
    for k, v in kv.items():
        d = s
        parts = k.split("__")
        for p in parts[:-1]:
            d = d[int(p)] if isinstance(d, list) else d[p]
        d[parts[-1]] = v
    return s


@pytest.mark.parametrize(
    "key,value",
    [
        ("sim__dt", 0.001),
        ("sim__substeps", 16),
        ("sim__precision", "f64"),
        ("output__every", 1),
        ("entities__0__material__E", 3e4),
        ("entities__0__velocity", [0.4, 0.0]),
        ("solvers__mpm__grid_density", 64.0),
    ],
)
def test_resume_refuses_what_changes_physics_or_time(key, value):
    diffs = scene_differences(SCENE, _changed(**{key: value}))
    assert len(diffs) == 1 and diffs[0].startswith(key.replace("__", ".") + ":"), diffs


def test_resume_allows_what_does_not():
    same = _changed(
        name="b",
        sim__steps=400,
        sim__threads=4,
        output__dir="elsewhere",
        output__formats=["hdf5", "vtk"],
        checkpoint__every=5,
        solvers__sph__particle_size=0.05,  # a family the scene does not use
    )
    assert scene_differences(SCENE, same) == []
    more = _changed()
    more["entities"].append({"name": "b2", "material": {"type": "MPM.Elastic", "E": 1e4}})
    assert any(d.startswith("entities.#") for d in scene_differences(SCENE, more))


def test_checkpoint_metadata_is_validated():
    good = {"step": 20, "frame": 10, "time": 20 * 0.004, "substeps_now": 8, "substeps_hist": [8] * 20}
    assert meta_problems(good, 0.004, 2, 40) == []
    for bad, what in [
        (dict(good, step=-20), "step = -20"),
        (dict(good, step=True), "step = True"),
        (dict(good, frame=7), "frame 7 does not match step 20"),
        (dict(good, time=0.5), "is not step * sim.dt"),
        (dict(good, time=float("nan")), "finite"),
        (dict(good, step=60, frame=30, time=60 * 0.004), "beyond the scene's last step 40"),
        (dict(good, substeps_now=0), "substeps_now"),
        (dict(good, substeps_hist=[8, "x"]), "substeps_hist"),
        (dict(good, dt_range=[1.0]), "dt_range"),
    ]:
        probs = meta_problems(bad, 0.004, 2, 40)
        assert probs and any(what in p for p in probs), (bad, probs)
