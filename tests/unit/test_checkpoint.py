"""Checkpoints: atomic writes, keep-newest-N, corrupt newest falls back to the previous one."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from simcli.errors import OutputError
from simcli.io import (
    CheckpointWarning,
    latest_checkpoint,
    list_checkpoints,
    read_checkpoint,
    write_checkpoint,
)
from simcli.io.checkpoint import load_latest_checkpoint

REPO = Path(__file__).resolve().parents[2]


def state(step: int) -> dict[str, np.ndarray]:
    return {
        "mpm/x": np.arange(30, dtype=np.float32).reshape(10, 3) + step,
        "mpm/v": np.full((10, 3), step, dtype=np.float64),
        "mpm/fixed": np.arange(10) % 2 == 0,
        "mpm/n_active": np.int64(step),
    }


def meta(step: int) -> dict:
    return {
        "frame": step // 10,
        "time": step * 1e-3,
        "substeps_hist": [10, 12],
        "scene_name": "t",
        "np_scalar": np.float32(0.5),
    }


def test_roundtrip(tmp_path):
    p = write_checkpoint(tmp_path, 100, state(100), meta(100), keep=2)
    assert p == tmp_path / "checkpoints" / "ckpt_00000100.npz"
    st, me = read_checkpoint(p)
    assert set(st) == set(state(100))
    for k, v in state(100).items():
        np.testing.assert_array_equal(st[k], v)
        assert st[k].dtype == np.asarray(v).dtype
    assert me["step"] == 100 and me["frame"] == 10 and me["substeps_hist"] == [10, 12]
    assert me["np_scalar"] == 0.5
    assert latest_checkpoint(tmp_path) == p
    # the runner passes OUT/checkpoints itself: the same folder
    assert latest_checkpoint(tmp_path / "checkpoints") == p
    assert write_checkpoint(tmp_path / "checkpoints", 200, state(200), meta(200), keep=2).parent == p.parent


def test_keep_newest(tmp_path):
    for step in (10, 20, 30, 40):
        write_checkpoint(tmp_path, step, state(step), meta(step), keep=2)
    assert [s for s, _ in list_checkpoints(tmp_path)] == [30, 40]
    write_checkpoint(tmp_path, 50, state(50), meta(50), keep=1)
    assert [s for s, _ in list_checkpoints(tmp_path)] == [50]
    write_checkpoint(tmp_path, 60, state(60), meta(60), keep=0)  # never deletes the one just written
    assert [s for s, _ in list_checkpoints(tmp_path)] == [60]


def test_later_checkpoints_of_an_abandoned_timeline_are_removed(tmp_path):
    for step in (10, 20, 30):
        write_checkpoint(tmp_path, step, state(step), meta(step), keep=5)
    write_checkpoint(tmp_path, 15, state(15), meta(15), keep=5)  # resumed from 10, now at 15
    assert [s for s, _ in list_checkpoints(tmp_path)] == [10, 15]
    assert latest_checkpoint(tmp_path).name == "ckpt_00000015.npz"


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty", "flip"])
def test_corrupt_newest_falls_back_to_previous(tmp_path, damage):
    write_checkpoint(tmp_path, 10, state(10), meta(10), keep=3)
    newest = write_checkpoint(tmp_path, 20, state(20), meta(20), keep=3)
    data = newest.read_bytes()
    if damage == "truncate":
        newest.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        newest.write_bytes(b"\0" * 100)
    elif damage == "empty":
        newest.write_bytes(b"")
    else:  # one flipped byte in the middle of an array: caught by the zip CRC
        i = data.index(b"NUMPY") + 200  # inside the data of the first array
        newest.write_bytes(data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1 :])
    with pytest.raises(ValueError, match="unreadable"):
        read_checkpoint(newest)
    with pytest.warns(CheckpointWarning, match="ckpt_00000020"):
        found = load_latest_checkpoint(tmp_path)
    assert found is not None
    path, st, me = found
    assert path.name == "ckpt_00000010.npz" and me["step"] == 10
    np.testing.assert_array_equal(st["mpm/x"], state(10)["mpm/x"])
    with pytest.warns(CheckpointWarning):
        assert latest_checkpoint(tmp_path).name == "ckpt_00000010.npz"


def test_no_checkpoint(tmp_path):
    assert latest_checkpoint(tmp_path) is None
    assert latest_checkpoint(tmp_path / "missing") is None
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "ckpt_00000001.npz").write_bytes(b"junk")
    with pytest.warns(CheckpointWarning):
        assert latest_checkpoint(tmp_path) is None


def test_failed_write_leaves_previous_intact(tmp_path, monkeypatch):
    good = write_checkpoint(tmp_path, 10, state(10), meta(10), keep=1)

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", boom)
    with pytest.raises(OutputError, match=r"ckpt_00000020\.npz: disk full"):
        write_checkpoint(tmp_path, 20, state(20), meta(20), keep=1)
    monkeypatch.undo()
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == [good.name]  # no temp left
    assert latest_checkpoint(tmp_path) == good


def test_killed_mid_write_leaves_no_partial_checkpoint(tmp_path):
    """SIGKILL while the npz is being written: only a temp file remains, ignored and cleaned up."""
    script = textwrap.dedent(
        f"""
        import os, signal, sys
        sys.path.insert(0, {str(REPO)!r})
        import numpy as np
        from simcli.io import write_checkpoint
        write_checkpoint({str(tmp_path)!r}, 10, {{"x": np.zeros(10)}}, {{}}, keep=2)
        real_fsync = os.fsync
        os.fsync = lambda fd: os.kill(os.getpid(), signal.SIGKILL)   # data written, not yet renamed
        write_checkpoint({str(tmp_path)!r}, 20, {{"x": np.ones(1_000_000)}}, {{}}, keep=2)
        """
    )
    r = subprocess.run([sys.executable, "-c", script])
    assert r.returncode == -signal.SIGKILL
    names = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert len(names) == 2 and names[0].startswith(".ckpt_00000020.npz.") and names[1] == "ckpt_00000010.npz"
    assert latest_checkpoint(tmp_path).name == "ckpt_00000010.npz"
    write_checkpoint(tmp_path, 30, {"x": np.zeros(3)}, {}, keep=2)
    names = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert names == ["ckpt_00000010.npz", "ckpt_00000030.npz"]


def test_unwritable_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match=str(blocker)):
        write_checkpoint(blocker, 1, {"x": np.zeros(1)}, {}, keep=1)


def test_reserved_names_and_no_pickles(tmp_path):
    with pytest.raises(ValueError, match="__"):
        write_checkpoint(tmp_path, 1, {"__meta__": np.zeros(1)}, {}, keep=1)
    with pytest.raises(ValueError, match="pickle"):  # object arrays would need pickle
        write_checkpoint(tmp_path, 2, {"o": np.array([{"a": 1}], dtype=object)}, {}, keep=1)
    assert not os.path.exists(tmp_path / "checkpoints")
