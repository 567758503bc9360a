"""``sim.h5``: every frame of every entity, written in HDF5 SWMR mode.

Layout (see SCENE_FORMAT.md section 3)::

    /                      attrs: format="simcli-frames", format_version=1, simcli_version, scene, + run attrs
    /time   (frames,)      float64, unit "s"
    /step   (frames,)      int64,   unit "1"
    /entities/<name>/      attrs: kind, dim, n (+ grid_shape, origin, spacing for grids)
        <field>            (frames, n[, comps]); grid fields (frames, nz, ny, nx[, comps]) in 3D,
                           (frames, ny, nx[, comps]) in 2D, with origin / spacing attrs (x, y, z)
        cells              (n_cells, nodes per cell) int64, static, meshes only
        vertices           (n,) int64 = 0..n-1, static, particles only (sim.xdmf's vertex cells)

Crash safety: all datasets are created first, then the file switches to SWMR mode; each
frame writes the entity datasets, flushes, and only then extends ``/time`` and ``/step`` and
flushes again.  A reader that trusts ``len(/time)`` never sees a half frame, and a SIGKILL
leaves every completed frame readable.

A file left by a killed writer still carries HDF5's "open for SWMR write" flags; open it with
``h5py.File(path, "r", swmr=True)`` (see :func:`open_frames`) or clear the flags first with
:func:`clear_status_flags` (what ``h5clear -s`` does) so that any HDF5 tool opens it.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from simcli.errors import OutputError

from .atomic import guard, output_error

if TYPE_CHECKING:  # pragma: no cover
    from .meta import EntityMeta

FORMAT = "simcli-frames"
FORMAT_VERSION = 1
# Lowest format that supports SWMR; capped at 1.10 so that every HDF5 >= 1.10 (ParaView/VTK's
# bundled copy, MATLAB, ...) reads the file.
LIBVER = ("v110", "v110")
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _h5file(path: Path, mode: str, **kw) -> h5py.File:
    try:
        return h5py.File(path, mode, locking="best-effort", **kw)
    except (TypeError, ValueError):  # h5py / HDF5 without best-effort locking
        return h5py.File(path, mode, **kw)


def open_frames(path: Path | str) -> h5py.File:
    """Open a sim.h5 for reading: works while it is written, after a crash, and after close."""
    return h5py.File(path, "r", swmr=True)


# -- superblock status flags (h5clear -s) ---------------------------------------------------

_M = 0xFFFFFFFF


def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & _M


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle``: the checksum HDF5 uses for its metadata."""
    length = len(data)
    a = b = c = (0xDEADBEEF + length + initval) & _M
    i = 0
    while length - i > 12:
        x, y, z = struct.unpack_from("<3I", data, i)
        a = (a + x) & _M
        b = (b + y) & _M
        c = (c + z) & _M
        a = (a - c) & _M
        a ^= _rot(c, 4)
        c = (c + b) & _M  # noqa: E702
        b = (b - a) & _M
        b ^= _rot(a, 6)
        a = (a + c) & _M  # noqa: E702
        c = (c - b) & _M
        c ^= _rot(b, 8)
        b = (b + a) & _M  # noqa: E702
        a = (a - c) & _M
        a ^= _rot(c, 16)
        c = (c + b) & _M  # noqa: E702
        b = (b - a) & _M
        b ^= _rot(a, 19)
        a = (a + c) & _M  # noqa: E702
        c = (c - b) & _M
        c ^= _rot(b, 4)
        b = (b + a) & _M  # noqa: E702
        i += 12
    rest = data[i:]
    if not rest:
        return c
    x, y, z = struct.unpack("<3I", rest.ljust(12, b"\0"))
    a = (a + x) & _M
    b = (b + y) & _M
    c = (c + z) & _M
    c ^= b
    c = (c - _rot(b, 14)) & _M  # noqa: E702
    a ^= c
    a = (a - _rot(c, 11)) & _M  # noqa: E702
    b ^= a
    b = (b - _rot(a, 25)) & _M  # noqa: E702
    c ^= b
    c = (c - _rot(b, 16)) & _M  # noqa: E702
    a ^= c
    a = (a - _rot(c, 4)) & _M  # noqa: E702
    b ^= a
    b = (b - _rot(a, 14)) & _M  # noqa: E702
    c ^= b
    c = (c - _rot(b, 24)) & _M  # noqa: E702
    return c


def superblock_info(path: Path | str) -> dict:
    """Where the HDF5 superblock is and what it says: base, version, flags, eoa (end of allocated
    space, relative to base) and the file's size. Raises OutputError saying what the file is instead."""
    path = Path(path)
    with guard(path, "read"), open(path, "rb") as fh:
        size = fh.seek(0, os.SEEK_END)
        base = 0
        while base + 64 <= size:
            fh.seek(base)
            if fh.read(8) == _HDF5_SIGNATURE:
                break
            base = 512 if base == 0 else base * 2
        else:
            fh.seek(0)
            head = fh.read(16)
            raise OutputError(f"{path}: not an HDF5 file ({size} bytes, starting {head!r})")
        fh.seek(base)
        head = fh.read(12)
        version = head[8]
        info = {"base": base, "version": version, "size": size, "flags": None, "eoa": None}
        if version < 2:
            return info
        so = head[9]
        if so not in (4, 8):
            raise OutputError(
                f"{path}: HDF5 superblock damaged (offset size {so}); the file cannot be repaired"
            )
        n = 12 + 4 * so
        fh.seek(base)
        sb = fh.read(n + 4)
        if len(sb) < n + 4:
            raise OutputError(
                f"{path}: HDF5 superblock cut short ({size} bytes); the file cannot be repaired"
            )
        (stored,) = struct.unpack_from("<I", sb, n)
        if lookup3(bytes(sb[:n])) != stored:
            raise OutputError(
                f"{path}: HDF5 superblock damaged (checksum mismatch): HDF5 cannot open the file and simcli "
                "cannot repair it"
            )
        (eoa,) = struct.unpack_from({4: "<I", 8: "<Q"}[so], sb, 12 + 2 * so)
        info.update(flags=head[11], eoa=eoa)
        return info


def extend_to_eoa(path: Path | str) -> tuple[int, int] | None:
    """A file that ends before the space HDF5 had allocated (a write cut short by a file-size limit or a
    full disk) is refused by HDF5 ("truncated file"); the missing bytes were never written, so zeros
    stand in for them (sparse). Returns (old size, new size) if extended. Raises OutputError."""
    path = Path(path)
    sb = superblock_info(path)
    end = sb["base"] + sb["eoa"] if sb["eoa"] is not None else 0
    if end <= sb["size"]:
        return None
    try:
        os.truncate(path, end)
    except OSError as e:
        raise OutputError(
            f"{path}: {sb['size']} bytes, shorter than the {end} HDF5 had allocated, and it cannot be "
            "extended: "
            f"{e.strerror or e}"
        ) from None
    return sb["size"], end


def clear_status_flags(path: Path | str) -> bool:
    """Clear the "file is open for (SWMR) write" flags a killed writer leaves in the superblock.

    Like ``h5clear -s -i``: also raises the end-of-allocation address to the file size so that
    space written after the last superblock update is never handed out twice.  Returns True if
    the file was changed.  Only for files no process has open for writing.
    """
    path = Path(path)
    with guard(path, "repair"), open(path, "r+b") as fh:
        size = fh.seek(0, os.SEEK_END)
        base = 0
        while base + 64 <= size:
            fh.seek(base)
            if fh.read(8) == _HDF5_SIGNATURE:
                break
            base = 512 if base == 0 else base * 2
        else:
            raise OutputError(f"{path}: not an HDF5 file")
        fh.seek(base)
        head = fh.read(12)
        version, so, _sl, flags = head[8], head[9], head[10], head[11]
        if version < 2:
            return False  # no consistency flags before superblock v2
        n = 12 + 4 * so
        fh.seek(base)
        sb = bytearray(fh.read(n + 4))
        (stored,) = struct.unpack_from("<I", sb, n)
        if lookup3(bytes(sb[:n])) != stored:
            raise OutputError(f"{path}: HDF5 superblock checksum mismatch; file is damaged")
        fmt = {4: "<I", 8: "<Q"}[so]
        eoa_off = 12 + 2 * so
        (eoa,) = struct.unpack_from(fmt, sb, eoa_off)
        new_eoa = max(eoa, size - base)
        if flags == 0 and new_eoa == eoa:
            return False
        sb[11] = 0
        struct.pack_into(fmt, sb, eoa_off, new_eoa)
        struct.pack_into("<I", sb, n, lookup3(bytes(sb[:n])))
        fh.seek(base)
        fh.write(bytes(sb))
        fh.flush()
        os.fsync(fh.fileno())
    return True


# -- the writer -----------------------------------------------------------------------------


def _attr_value(v):
    if isinstance(v, (str, bytes, bool, int, float, np.generic)):
        return v
    if isinstance(v, np.ndarray) and v.dtype.kind in "biuf":
        return v
    if isinstance(v, (list, tuple)) and v and all(type(x) in (int, float) for x in v):
        return np.asarray(v)
    return json.dumps(v, default=str)


class H5Writer:
    """Writes sim.h5; used by :class:`simcli.io.frames.FrameSink`."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.f: h5py.File | None = None
        self.entities: list[EntityMeta] = []
        self._ds: list[tuple[h5py.Dataset, str, str]] = []  # (dataset, entity, field)
        self._cds: list[tuple[h5py.Dataset, str, str]] = []  # (dataset, collider, force|torque)
        self.colliders: dict[str, int] = {}
        self._times: list[float] = []
        self._fd: int | None = None  # HDF5's file descriptor (sec2 driver)
        self._ident: tuple[int, int] | None = None  # (st_dev, st_ino) of the file we write
        self._size = 0  # its size after the last complete frame
        self._series: dict[str, tuple] = {}  # probes: name -> (time, value, samples held)

    # -- faults -----------------------------------------------------------------------------
    def _kept(self) -> str:
        n = len(self._times)
        return (
            f"the {n} frame(s) completed before are kept (`simcli repair {self.path.parent}` makes the "
            f"file openable by every HDF5 tool)"
        )

    def _watch(self) -> None:
        """Remember which file HDF5 writes (inode) and how large it is after a complete frame."""
        try:
            self._fd = int(self.f.id.get_vfd_handle())
            st = os.fstat(self._fd)
        except Exception:  # noqa: BLE001 - another driver: no checks, nothing lost by that
            self._fd = None
            return
        self._ident = (st.st_dev, st.st_ino)
        self._size = st.st_size

    def _check_intact(self) -> None:
        """sim.h5 deleted, replaced or truncated by someone else since the last frame: stop with exit 74
        rather than write on into a file nobody will see (Linux keeps writing to a deleted inode)."""
        if self._fd is None or self._ident is None:
            return
        try:
            st = os.fstat(self._fd)
        except OSError:
            return
        try:
            ps = os.stat(self.path)
        except FileNotFoundError:
            ps = None
        except OSError:
            return
        if ps is None:
            restored = self._restore_deleted()
            raise OutputError(
                f"{self.path} was deleted by another process while this run was writing it: "
                + (
                    f"its {len(self._times)} completed frame(s) were written back to {self.path} (run "
                    f"`simcli repair {self.path.parent}` before opening it); the run stops here"
                    if restored
                    else f"it could not be written back ({restored}); the run stops here"
                )
            )
        if (ps.st_dev, ps.st_ino) != self._ident:
            raise OutputError(
                f"{self.path} was replaced by another file while this run was writing it (a second run into "
                f"the same folder?): this run's frames are not in it; the run stops here"
            )
        if st.st_size < self._size:
            raise OutputError(
                f"{self.path} was truncated by another process while this run was writing it "
                f"({self._size} -> "
                f"{st.st_size} bytes): the frames in it are lost (the files under vtk/, if written, keep "
                f"theirs); the run stops here"
            )

    def _restore_deleted(self):
        """Copy the still-open, deleted file (consistent as of the last complete frame) back to its name."""
        tmp = self.path.with_name("." + self.path.name + ".restore.tmp")
        try:
            with open(tmp, "wb") as out:
                off = 0
                while True:
                    b = os.pread(self._fd, 1 << 22, off)
                    if not b:
                        break
                    out.write(b)
                    off += len(b)
                out.flush()
                os.fsync(out.fileno())
            if self.path.exists():
                tmp.unlink()
                return False
            os.replace(tmp, self.path)
            return True
        except OSError as e:
            try:
                tmp.unlink()
            except OSError:
                pass
            return e.strerror or str(e)

    def abandon(self) -> None:
        """Close the file after a failed write without writing anything more into it.

        After a failed flush HDF5 keeps dirty metadata that it retries to write on close and again when
        the library shuts down at exit (where a failure crashes the process: SIGSEGV/SIGBUS under a
        file-size limit). Pointing HDF5's descriptor at /dev/null first lets both succeed and leaves the
        file on disk as the last complete frame left it: every completed frame readable, the
        open-for-writing flag set (``simcli repair`` clears it)."""
        f, self.f = self.f, None
        fd, self._fd = self._fd, None
        if f is None:
            return
        if fd is not None:  # first: closing a dataset flushes it too
            try:
                nul = os.open(os.devnull, os.O_RDWR)
                os.dup2(nul, fd)
                os.close(nul)
            except OSError:
                pass
        self._ds = []
        self._series = {}
        self._cds = []
        self._time = self._step = None
        try:
            f.close()
        except Exception:  # noqa: BLE001, S110 - nothing more can be done: the data on disk is what counts
            pass

    def times(self) -> list[float]:
        return list(self._times)

    def counts(self) -> list[dict[str, int]]:
        """Per frame held: the live count of each entity whose count varies."""
        k = len(self._times)
        per = {
            e.name: [int(c) for c in self._fsd[f"entities/{e.name}/count"][:k]]
            for e in self.entities
            if e.variable
        }
        return [{name: c[i] for name, c in per.items()} for i in range(k)]

    # ------------------------------------------------------------------------------------
    def open(
        self,
        entities: list[EntityMeta],
        scene_text: str,
        attrs: dict,
        resume_frame: int | None,
        series: dict[str, tuple[int, str]] | None = None,
        series_until: float | None = None,
        colliders: dict[str, int] | None = None,
        frame_series: dict[str, str] | None = None,
    ) -> None:
        from simcli import __version__

        self.entities = list(entities)
        self.colliders = dict(colliders or {})
        # per-frame scalars (sim.h5 path -> unit): the live count of each entity whose count varies, and
        # the caller's (emitted and removed mass)
        self.frame_series = {f"entities/{e.name}/count": "1" for e in self.entities if e.variable}
        self.frame_series.update(frame_series or {})
        self._fsd: dict = {}
        if resume_frame is None:
            with guard(self.path, "create"):
                f = _h5file(self.path, "w", libver=LIBVER)
            self.f = f
            with guard(self.path):
                self._create(f)
        else:
            if not self.path.exists():
                raise OutputError(f"cannot resume: {self.path} does not exist")
            extend_to_eoa(self.path)
            clear_status_flags(self.path)
            with guard(self.path, "open for append"):
                f = _h5file(self.path, "a", libver=LIBVER)
            self.f = f
            with guard(self.path):
                self._reopen(f, resume_frame)
        if series:
            with guard(self.path):
                self._open_series(f, series, series_until if resume_frame is not None else None)
        with guard(self.path):
            f.attrs["format"] = FORMAT
            f.attrs["format_version"] = FORMAT_VERSION
            f.attrs["simcli_version"] = __version__
            f.attrs["scene"] = scene_text
            for k, v in (attrs or {}).items():
                if k in ("format", "format_version", "simcli_version", "scene"):
                    continue
                f.attrs[k] = _attr_value(v)
            f.flush()
            f.swmr_mode = True
        self._watch()

    def _create(self, f: h5py.File) -> None:
        t = f.create_dataset("time", shape=(0,), maxshape=(None,), chunks=(1024,), dtype="f8")
        t.attrs["unit"] = "s"
        s = f.create_dataset("step", shape=(0,), maxshape=(None,), chunks=(1024,), dtype="i8")
        s.attrs["unit"] = "1"
        ents = f.create_group("entities")
        for e in self.entities:
            g = ents.create_group(e.name)
            g.attrs["kind"] = e.kind
            g.attrs["dim"] = e.dim
            g.attrs["n"] = e.n
            if e.kind == "grid":
                g.attrs["grid_shape"] = np.asarray(e.grid_shape, dtype="i8")
                g.attrs["origin"] = np.asarray(e.origin, dtype="f8")
                g.attrs["spacing"] = np.asarray(e.spacing, dtype="f8")
            if e.variable:
                g.attrs["variable_count"] = True  # rows past /entities/<name>/count[frame] are padding
            if e.cells is not None:
                c = g.create_dataset("cells", data=e.cells, dtype="i8")
                c.attrs["unit"] = "1"
            elif e.kind == "particles":
                # one vertex cell per particle, for sim.xdmf: ParaView's XDMF 3 reader builds no cells
                # for a Polyvertex topology without connectivity (nothing shows in its Surface view)
                v = g.create_dataset("vertices", data=np.arange(e.n, dtype="i8"), dtype="i8")
                v.attrs["unit"] = "1"
            for fname, (_comps, unit, dtype) in e.fields.items():
                shape = e.frame_shape(fname)
                d = g.create_dataset(
                    fname, shape=(0,) + shape, maxshape=(None,) + shape, chunks=(1,) + shape, dtype=dtype
                )
                d.attrs["unit"] = unit
                if e.kind == "grid":
                    d.attrs["origin"] = np.asarray(e.origin, dtype="f8")
                    d.attrs["spacing"] = np.asarray(e.spacing, dtype="f8")
                    d.attrs["center"] = "cell"
                elif fname in e.cell_fields:  # one value per cell of the mesh (rows of "cells")
                    d.attrs["center"] = "cell"
                self._ds.append((d, e.name, fname))
        for path, unit in self.frame_series.items():
            dt = "i8" if path.endswith("/count") else "f8"
            d = f.create_dataset(path, shape=(0,), maxshape=(None,), chunks=(1024,), dtype=dt)
            d.attrs["unit"] = unit
            self._fsd[path] = d
        if self.colliders:
            cg = f.create_group("colliders")
            for name, dim in self.colliders.items():
                g = cg.create_group(name)
                for fname, n, unit in (("force", dim, "N"), ("torque", 3 if dim == 3 else 1, "N m")):
                    d = g.create_dataset(fname, shape=(0, n), maxshape=(None, n), chunks=(64, n), dtype="f8")
                    d.attrs["unit"] = unit
                    self._cds.append((d, name, fname))
        self._time, self._step = t, s
        self._times = []

    def _reopen(self, f: h5py.File, k: int) -> None:
        if f.attrs.get("format") != FORMAT:
            raise OutputError(f"cannot resume: {self.path} is not a simcli frames file")
        t, s = f["time"], f["step"]
        nframes = min(t.shape[0], s.shape[0])
        if k > nframes:
            raise OutputError(f"cannot resume at frame {k}: {self.path} holds only {nframes} complete frames")
        for e in self.entities:
            gpath = f"entities/{e.name}"
            if gpath not in f:
                raise OutputError(f"cannot resume: {self.path} has no entity {e.name!r} (scene changed?)")
            g = f[gpath]
            for fname, (_c, _u, dtype) in e.fields.items():
                if fname not in g:
                    raise OutputError(
                        f"cannot resume: {self.path} has no field {e.name}/{fname} (scene changed?)"
                    )
                d = g[fname]
                if d.shape[1:] != e.frame_shape(fname) or d.shape[0] < k:
                    raise OutputError(
                        f"cannot resume: {self.path} {e.name}/{fname} has shape {d.shape}, "
                        f"expected (>= {k},) + {e.frame_shape(fname)} (scene changed?)"
                    )
                d.resize(k, axis=0)
                self._ds.append((d, e.name, fname))
        for path in self.frame_series:
            if path not in f or f[path].shape[0] < k:
                raise OutputError(f"cannot resume: {self.path} has no complete {path} (scene changed?)")
            f[path].resize(k, axis=0)
            self._fsd[path] = f[path]
        for name in self.colliders:
            for fname in ("force", "torque"):
                path = f"colliders/{name}/{fname}"
                if path not in f or f[path].shape[0] < k:
                    raise OutputError(f"cannot resume: {self.path} has no complete {path} (scene changed?)")
                f[path].resize(k, axis=0)
                self._cds.append((f[path], name, fname))
        t.resize(k, axis=0)
        s.resize(k, axis=0)
        self._time, self._step = t, s
        self._times = [float(x) for x in t[:k]]

    def _open_series(self, f: h5py.File, series: dict, until: float | None) -> None:
        """/probes/<name>/time (samples,) and /value (samples[, components]), float64; created before the
        file switches to SWMR mode; on a resume cut back to the samples at times <= ``until``."""
        g = f.require_group("probes")
        for name, (comps, unit) in series.items():
            shape = (comps,) if comps > 1 else ()
            if name in g and until is not None:
                t, v = g[name]["time"], g[name]["value"]
                if v.shape[1:] != shape:
                    raise OutputError(
                        f"cannot resume: {self.path} probe {name} has shape {v.shape}, expected "
                        f"(n,) + {shape}"
                    )
                times = t[: min(t.shape[0], v.shape[0])]
                k = int(np.count_nonzero(times <= until))
                t.resize(k, axis=0)
                v.resize(k, axis=0)
            else:
                if name in g:
                    del g[name]
                pg = g.create_group(name)
                t = pg.create_dataset("time", shape=(0,), maxshape=(None,), chunks=(256,), dtype="f8")
                t.attrs["unit"] = "s"
                v = pg.create_dataset(
                    "value", shape=(0,) + shape, maxshape=(None,) + shape, chunks=(256,) + shape, dtype="f8"
                )
                v.attrs["unit"] = unit
            self._series[name] = (t, v, int(t.shape[0]))  # datasets and the samples they hold

    def write_series(self, samples: dict, flush: bool = True) -> None:
        """Append samples, name -> [(time, value), ...], to the named series: the values first, flushed, then
        the times, flushed (a reader that trusts len(time) never sees a missing value). ``flush=False`` when a
        frame is written next, whose flushes write these too."""
        f = self.f
        assert f is not None, "H5Writer not open"
        try:
            for name, rows in samples.items():
                tds, vds, n = self._series[name]
                k = len(rows)
                vals = np.ascontiguousarray([v for _t, v in rows], dtype=np.float64).reshape(
                    (k,) + vds.shape[1:]
                )
                vds.resize(n + k, axis=0)
                vds.write_direct(vals, dest_sel=np.s_[n : n + k])
            if flush:
                f.flush()
            for name, rows in samples.items():
                tds, vds, n = self._series[name]
                k = len(rows)
                tds.resize(n + k, axis=0)
                tds.write_direct(
                    np.asarray([t for t, _v in rows], dtype=np.float64), dest_sel=np.s_[n : n + k]
                )
                self._series[name] = (tds, vds, n + k)
            if flush:
                f.flush()
        except (OSError, RuntimeError) as exc:
            err = output_error(self.path, exc)
            self.abandon()
            raise OutputError(f"{err}; {self._kept()}") from exc

    # ------------------------------------------------------------------------------------
    def write_frame(
        self,
        frame: int,
        step: int,
        time: float,
        data: dict[str, dict[str, np.ndarray]],
        colliders: dict[str, dict[str, np.ndarray]] | None = None,
        values: dict[str, float] | None = None,
    ) -> None:
        f = self.f
        assert f is not None, "H5Writer not open"
        if frame != len(self._times):
            raise ValueError(f"sim.h5 holds {len(self._times)} frames; cannot write frame {frame}")
        try:
            self._check_intact()
        except OutputError:
            self.abandon()
            raise
        try:
            counts = {}
            for d, ename, fname in self._ds:
                d.resize(frame + 1, axis=0)
                a = data[ename][fname]
                if a.shape != d.shape[1:]:  # a varying count: the live rows, then padding (NaN, -1)
                    counts[ename] = a.shape[0]
                    pad = np.full(d.shape[1:], np.nan if a.dtype.kind == "f" else -1, dtype=a.dtype)
                    pad[: a.shape[0]] = a
                    a = pad
                elif f"entities/{ename}/count" in self._fsd:
                    counts[ename] = a.shape[0]
                d.write_direct(np.ascontiguousarray(a), dest_sel=np.s_[frame])
            vals = dict(values or {})
            vals.update({f"entities/{k}/count": c for k, c in counts.items()})
            for path, d in self._fsd.items():
                d.resize(frame + 1, axis=0)
                d[frame] = vals.get(path, 0)
            for d, cname, fname in self._cds:
                d.resize(frame + 1, axis=0)
                d[frame] = np.asarray((colliders or {})[cname][fname], dtype="f8").reshape(d.shape[1:])
            f.flush()  # the frame's data is on disk before /time says it exists
            self._step.resize(frame + 1, axis=0)
            self._step[frame] = step
            self._time.resize(frame + 1, axis=0)
            self._time[frame] = time
            f.flush()
        except (OSError, RuntimeError) as exc:
            err = output_error(self.path, exc)
            self.abandon()
            raise OutputError(f"{err}; {self._kept()}") from exc
        self._times.append(time)
        if self._fd is not None:
            try:
                self._size = os.fstat(self._fd).st_size
            except OSError:
                pass

    def close(self) -> None:
        if self.f is None:
            return
        try:
            self._check_intact()
        except OutputError:
            self.abandon()
            raise
        try:
            self.f.close()
        except (OSError, RuntimeError) as exc:
            err = output_error(self.path, exc, "close")
            self.abandon()
            raise OutputError(f"{err}; {self._kept()}") from exc
        self.f, self._fd, self._ds, self._series, self._cds = None, None, [], {}, []
