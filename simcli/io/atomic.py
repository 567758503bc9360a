"""Atomic files and OS-error translation shared by the writers, the sink and the checkpoints: a file is
written at a temporary name and renamed over its target, and OS / HDF5 errors become ``OutputError``
naming the path (disk full, quota, permissions spelled out). A leaf module of ``simcli.io``."""

from __future__ import annotations

import errno
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO, Iterator

from simcli.errors import OutputError


def output_error(path: Path | str, exc: BaseException, what: str = "write") -> OutputError:
    """An OutputError naming the path, with 'disk full' spelled out when that is the cause."""
    err = getattr(exc, "errno", None)
    text = str(exc)
    if err == errno.ENOSPC or "No space left" in text:
        reason = "disk full (no space left on device)"
    elif err == errno.EFBIG or "File too large" in text:
        reason = "file too large (the file-size limit, `ulimit -f`, reached)"
    elif err == errno.EDQUOT or "quota" in text.lower():
        reason = "disk quota exceeded"
    elif err in (errno.EACCES, errno.EPERM, errno.EROFS) or "ermission denied" in text:
        reason = "permission denied (folder not writable)"
    else:
        reason = text or type(exc).__name__
    out = OutputError(f"cannot {what} {path}: {reason}")
    out.path = str(path)  # type: ignore[attr-defined]
    return out


@contextmanager
def guard(path: Path | str, what: str = "write") -> Iterator[None]:
    """Turn OS / HDF5 errors into OutputError naming ``path``."""
    try:
        yield
    except OutputError:
        raise
    except (OSError, RuntimeError) as exc:  # h5py raises OSError / RuntimeError subclasses
        raise output_error(path, exc, what) from exc


def ensure_dir(path: Path) -> Path:
    with guard(path, "create folder"):
        path.mkdir(parents=True, exist_ok=True)
        if not os.access(path, os.W_OK | os.X_OK):
            raise PermissionError(errno.EACCES, "permission denied", str(path))
    return path


@contextmanager
def atomic_file(path: Path, fsync: bool = False, mode: int | None = None) -> Iterator[BinaryIO]:
    """A binary file at a temporary name in ``path``'s folder, renamed over ``path`` when the block ends
    without an error (fsynced first if asked, then given the permissions ``mode`` if set; mkstemp's
    are 0600); deleted when it raises."""
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def atomic_write_bytes(path: Path, data: bytes | list[bytes], fsync: bool = False) -> None:
    """Write to a temporary name in the same folder, then ``os.replace`` it over ``path``.

    A reader (or a run killed at any point) sees either the old or the new content.
    ``fsync`` additionally makes it durable against a power loss (slower).
    """
    path = Path(path)
    chunks = [data] if isinstance(data, (bytes, bytearray, memoryview)) else data
    with guard(path), atomic_file(path, fsync=fsync, mode=0o644) as fh:
        for c in chunks:
            fh.write(c)


def atomic_write_text(path: Path, text: str, fsync: bool = False) -> None:
    atomic_write_bytes(path, text.encode("utf-8"), fsync=fsync)
