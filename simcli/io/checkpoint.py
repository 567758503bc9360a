"""Restart files: ``OUT/checkpoints/ckpt_<step:08d>.npz``.

Each checkpoint is one uncompressed ``.npz`` holding the solver state arrays plus the run
metadata as JSON (member ``__meta__``, a uint8 array of UTF-8 bytes; no pickles).  It is
written to a temporary name, fsynced, renamed over the final name and the folder fsynced, so
a checkpoint either exists completely or not at all.  Only the newest ``keep`` survive.

Reading verifies the zip CRC of every member; a truncated or corrupt newest checkpoint is
skipped (with a warning) in favour of the previous one.
"""

from __future__ import annotations

import json
import logging
import os
import re
import warnings
import zipfile
from pathlib import Path

import numpy as np

from .atomic import atomic_file, guard

log = logging.getLogger(__name__)

META_KEY = "__meta__"
_NAME = re.compile(r"^ckpt_(\d{8,})\.npz$")


class CheckpointWarning(UserWarning):
    """A checkpoint was unreadable and skipped."""


def checkpoint_dir(dir: Path | str) -> Path:
    """``dir/checkpoints``; ``dir`` itself if it is already named ``checkpoints``."""
    d = Path(dir)
    return d if d.name == "checkpoints" else d / "checkpoints"


def list_checkpoints(dir: Path | str) -> list[tuple[int, Path]]:
    """(step, path) of every checkpoint file, oldest first (not validated)."""
    d = checkpoint_dir(dir)
    if not d.is_dir():
        return []
    out = []
    for p in d.iterdir():
        m = _NAME.match(p.name)
        if m and p.is_file():
            out.append((int(m.group(1)), p))
    return sorted(out)


def _fsync_dir(d: Path) -> None:
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_checkpoint(dir: Path | str, step: int, state: dict[str, np.ndarray], meta: dict, keep: int) -> Path:
    """Write ``ckpt_<step>.npz`` atomically; keep the newest ``keep`` (at least this one).

    ``meta`` must be JSON-serialisable (numpy scalars / arrays are converted); ``step`` is
    added to it.  Checkpoints with a larger step than this one belong to an abandoned
    timeline (the run was resumed from an earlier one) and are deleted too.
    """
    if step < 0:
        raise ValueError("step must be >= 0")
    bad = [k for k in state if k.startswith("__")]
    if bad:
        raise ValueError(f"state keys must not start with '__': {bad}")
    d = checkpoint_dir(dir)
    final = d / f"ckpt_{int(step):08d}.npz"
    meta = dict(meta)
    meta.setdefault("step", int(step))
    meta_bytes = json.dumps(meta, default=_json_default, sort_keys=True).encode("utf-8")
    arrays = {k: np.asarray(v) for k, v in state.items()}
    objs = [k for k, a in arrays.items() if a.dtype.hasobject]
    if objs:
        raise ValueError(
            f"state arrays {objs} hold Python objects; checkpoints store numbers only (no pickle)"
        )
    arrays[META_KEY] = np.frombuffer(meta_bytes, dtype=np.uint8)
    with guard(final, "write checkpoint"):
        d.mkdir(parents=True, exist_ok=True)
        with atomic_file(final, fsync=True) as fh:
            np.savez(fh, **arrays)
        _fsync_dir(d)
    _prune(d, int(step), max(int(keep), 1))
    return final


def _prune(d: Path, step: int, keep: int) -> None:
    ckpts = list_checkpoints(d)
    older = [(s, p) for s, p in ckpts if s <= step]
    doomed = [p for s, p in ckpts if s > step] + [p for _s, p in older[: max(len(older) - keep, 0)]]
    for p in doomed:
        try:
            p.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            log.warning("could not delete old checkpoint %s: %s", p, exc)
    for p in d.glob(".ckpt_*.tmp"):  # left by a killed writer
        try:
            p.unlink()
        except OSError:
            pass


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"checkpoint meta: {type(o).__name__} is not JSON serialisable")


def read_checkpoint(path: Path | str) -> tuple[dict[str, np.ndarray], dict]:
    """(state, meta) of one checkpoint; raises ``ValueError`` if it is truncated or corrupt."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            state = {k: z[k] for k in z.files}  # reading checks every member's CRC
    except FileNotFoundError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zipfile.LargeZipFile) as exc:
        raise ValueError(f"checkpoint {path} is unreadable (truncated or corrupt): {exc}") from exc
    raw = state.pop(META_KEY, None)
    if raw is None:
        raise ValueError(f"checkpoint {path} has no metadata")
    try:
        meta = json.loads(raw.tobytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"checkpoint {path} has corrupt metadata: {exc}") from exc
    return state, meta


def load_latest_checkpoint(dir: Path | str) -> tuple[Path, dict[str, np.ndarray], dict] | None:
    """(path, state, meta) of the newest readable checkpoint, or None; warns about skipped ones."""
    for _step, p in reversed(list_checkpoints(dir)):
        try:
            state, meta = read_checkpoint(p)
        except (ValueError, OSError) as exc:
            msg = f"skipping unreadable checkpoint {p}: {exc}"
            warnings.warn(msg, CheckpointWarning, stacklevel=2)
            continue
        return p, state, meta
    return None


def latest_checkpoint(dir: Path | str) -> Path | None:
    """Path of the newest readable checkpoint (every member verified), or None."""
    found = load_latest_checkpoint(dir)
    return None if found is None else found[0]
