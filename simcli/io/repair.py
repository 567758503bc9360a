"""``simcli repair OUT``: make the sim.h5 of a stopped run openable by every HDF5 tool, and say how
many frames it holds only after reading each of them.

What it does to a sim.h5 left by a killed run or a failed write (file-size limit, disk full): clears
the "open for writing" flags HDF5 keeps in the superblock (``h5clear -s``), and where the file ends
before the space HDF5 had allocated (a write cut short by the limit), extends it to that size so that
HDF5 opens it (the missing part only ever held the frame being written). Then every frame of every
field is read and its chunk checked to lie inside what was on disk; the count reported is the number of
consecutive frames from 0 that passed.

Anything else (no sim.h5, a folder, an empty or plain-text file, a damaged superblock, frames that
do not read back) is an OutputError (exit 74) that says what was found; nothing is guessed."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simcli.errors import OutputError

from .outdir import OutputLock


def _verify(f, size: int) -> tuple[int, int, str | None]:
    """(frames verified from frame 0, frames listed, why the first bad one is bad)."""
    for k in ("time", "step"):
        if k not in f:
            return 0, 0, f"no /{k} dataset"
    t = f["time"][...]
    n = int(min(len(t), len(f["step"])))
    ds = []
    ents = f.get("entities")
    if ents is None:
        return 0, n, "no /entities group"

    def visit(name, obj):
        if hasattr(obj, "shape") and name.split("/")[-1] not in ("cells", "vertices"):  # static topology
            ds.append(obj)

    ents.visititems(visit)
    for obj in ds:
        if obj.shape[0] < n:
            return 0, n, f"{obj.name} holds {obj.shape[0]} frames, /time lists {n}"
    for d in (f["time"], f["step"]):
        c = d.chunks[0] if d.chunks else None
        for start in range(0, n, c or max(n, 1)) if c else []:
            info = d.id.get_chunk_info_by_coord((start,))
            if info.byte_offset is None or info.byte_offset + info.size > size:
                return start, n, f"{d.name} (from frame {start}) lies beyond the end of the file as written"
    for i in range(n):
        if not np.isfinite(t[i]):
            return i, n, f"frame {i}: /time is {t[i]}"
        for d in ds:
            try:
                info = d.id.get_chunk_info_by_coord((i,) + (0,) * (len(d.shape) - 1))
                if info.byte_offset is None or info.byte_offset + info.size > size:
                    return i, n, f"frame {i}: {d.name} lies beyond the end of the file as written"
                d[i]
            except Exception as e:  # noqa: BLE001 - any failure to read the frame back is what we report
                return i, n, f"frame {i}: {d.name} cannot be read ({type(e).__name__}: {e})"
    return n, n, None


def repair(out: Path) -> str:
    """Repair OUT/sim.h5; returns the message for the user; raises OutputError (exit 74)."""
    import h5py

    from .hdf5 import FORMAT, clear_status_flags, extend_to_eoa

    out = Path(out)
    if out.is_file() and out.name.endswith(".h5"):  # the file itself given: its folder
        out = out.parent
    if not out.exists():
        raise OutputError(f"{out}: no such folder (give the run's output folder)")
    if not out.is_dir():
        raise OutputError(f"{out}: not a folder (give the run's output folder, which holds sim.h5)")
    h5 = out / "sim.h5"
    with OutputLock(out, "simcli repair"):  # not while a run writes it
        if not h5.exists() and not h5.is_symlink():
            raise OutputError(
                f"{h5}: not found (nothing to repair: the run wrote no HDF5 output, or it was removed)"
            )
        if h5.is_dir():
            raise OutputError(f"{h5}: is a folder, not an HDF5 file; nothing to repair")
        if not h5.is_file():
            raise OutputError(f"{h5}: is not a regular file (a broken link or a device); nothing to repair")
        size = h5.stat().st_size
        if size == 0:
            raise OutputError(
                f"{h5}: empty (0 bytes): the run stopped, or the file was truncated, before any frame"
            )
        did = []
        grown = extend_to_eoa(h5)
        if grown:
            # the missing bytes only ever held the frame being written; every frame is checked below against
            # the part that was on disk
            did.append(
                f"extended it from {grown[0]} to {grown[1]} bytes: it ended before the space HDF5 had "
                "allocated (a write cut short, or the file truncated)"
            )
        if clear_status_flags(h5):
            did.append("cleared the open-for-writing flag")
        try:
            f = h5py.File(h5, "r")
        except Exception as e:  # noqa: BLE001
            raise OutputError(f"{h5}: HDF5 cannot open it ({e}); it cannot be repaired") from None
        with f:
            if f.attrs.get("format") != FORMAT:
                raise OutputError(
                    f"{h5}: an HDF5 file but not simcli frames (format {f.attrs.get('format')!r})"
                )
            ok, n, why = _verify(f, size)
        what = "; ".join(did) if did else "already clean"
        if why is not None:
            raise OutputError(
                f"{h5}: {what}; only {ok} of the {n} frame(s) it lists read back intact ({why}). Frames "
                f"0-{ok - 1} are good; resume from a checkpoint or run again for the rest"
                if ok
                else f"{h5}: {what}; no frame reads back intact ({why})"
            )
        return f"{h5}: {what}; {ok} frames readable (each one read back)"
