"""One run per output folder at a time, and no silent overwrite of a previous run.

``OUT/.simcli.lock`` is held with an exclusive ``flock`` for the whole run (and by ``simcli repair``).
The kernel releases it when the process ends in any way, SIGKILL and out-of-memory kills included, so a
killed run leaves nothing stuck; the file itself stays and only says who held it last (pid, host). On
NFS, Linux implements ``flock`` with POSIX byte-range locks, which the server arbitrates across hosts.

A folder that holds a previous run (its run.json, sim.h5, frames or checkpoints) is only written into
with ``--resume`` (continue it) or ``--overwrite`` (replace it: the previous run's outputs are removed
first, so that none of its frames or checkpoints survive into the new one)."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import platform
import shutil
from pathlib import Path

from simcli.errors import EXIT_USAGE, OutputError, SimcliError

LOCK_NAME = ".simcli.lock"
# what a run writes into OUT (what --overwrite removes; nothing else in the folder is touched)
RUN_FILES = ("run.json", "scene.yaml", "sim.h5", "sim.xdmf", "probes.csv")
RUN_DIRS = ("vtk", "checkpoints")


class OutputBusy(OutputError):
    """Another process holds the output folder's lock (exit 74)."""


class PreviousRun(SimcliError):
    """The output folder holds a previous run and neither --overwrite nor --resume was given (exit 2)."""

    exit_code = EXIT_USAGE


def _holder(path: Path) -> str:
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
        return f"pid {d.get('pid')} on {d.get('host')}" + (f" ({d['what']})" if d.get("what") else "")
    except (OSError, ValueError, AttributeError):
        return "another process"


class OutputLock:
    """An exclusive lock on ``OUT/.simcli.lock``; released by :meth:`release` or when the process ends."""

    def __init__(self, out: Path, what: str = "simcli run"):
        self.out = Path(out)
        self.path = self.out / LOCK_NAME
        self.what = what
        self.fd: int | None = None

    def acquire(self) -> "OutputLock":
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as e:
            raise OutputError(f"cannot create the lock file {self.path}: {e.strerror or e}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise OutputBusy(
                    f"output folder {self.out} is in use by {_holder(self.path)}: one run writes a folder at "
                    f"a time. Wait for it to end, stop it, or choose another folder with -o"
                ) from None
            raise OutputError(f"cannot lock {self.path}: {e.strerror or e}") from None
        self.fd = fd
        self.info = {"pid": os.getpid(), "host": platform.node(), "what": self.what, "file": str(self.path)}
        try:  # who holds it, for the message a second run prints (best effort: the lock is what counts)
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(self.info) + "\n").encode(), 0)
        except OSError:
            pass
        return self

    def release(self) -> None:
        fd, self.fd = self.fd, None
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)

    def __enter__(self) -> "OutputLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def previous_run(out: Path) -> str | None:
    """What of a previous run ``out`` holds (None: nothing; a fresh run may write there). Only outputs
    count (frames, checkpoints): a run.json and scene.yaml alone are the record of a run that stopped
    before it wrote anything (an invalid scene, a signal during start-up) and are simply replaced."""
    out = Path(out)
    found = [n for n in ("sim.h5", "sim.xdmf") if (out / n).exists()]
    found += [n + "/" for n in RUN_DIRS if (out / n).is_dir() and any((out / n).iterdir())]
    if not found:
        return None
    status = ""
    try:
        d = json.loads((out / "run.json").read_text(encoding="utf-8"))
        status = f"a run with status '{d.get('status')}'"
        if d.get("steps_done") is not None:
            status += f" after {d.get('steps_done')} steps"
        status += ": "
    except (OSError, ValueError, AttributeError):
        pass
    return status + ", ".join(found)


def refuse_previous_run(out: Path) -> None:
    what = previous_run(out)
    if what is not None:
        raise PreviousRun(
            f"output folder {out} holds a previous run ({what}). Pass --overwrite to replace it, --resume to "
            f"continue it from its newest checkpoint, or choose another folder with -o"
        )


def remove_previous_run(out: Path) -> list[str]:
    """Remove what a run writes into ``out`` (for --overwrite); returns the names removed."""
    out = Path(out)
    gone = []
    try:
        for n in RUN_FILES:
            p = out / n
            if p.is_file() or p.is_symlink():
                p.unlink()
                gone.append(n)
        for n in RUN_DIRS:
            p = out / n
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
                gone.append(n + "/")
    except OSError as e:
        raise OutputError(
            f"--overwrite: cannot remove the previous run's {e.filename or out}: {e.strerror or e}"
        ) from None
    return gone
