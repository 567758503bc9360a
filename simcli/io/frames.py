"""Entity descriptions, shared helpers and the ``FrameSink`` that fans frames out to the writers.

The writers know nothing of physics: they receive, per frame, one dict of numpy arrays per
entity (``{entity: {field: array}}``) and the static description of each entity
(:class:`EntityMeta`) once, when the output is opened.

Array conventions (what ``write_frame`` accepts):

* particles / meshes: ``position`` (n, dim), vector fields (n, dim), scalars (n,), any other
  field (n, components) (an (n, 3, 3) tensor is accepted for 9 components).
* grids (``kind="grid"``, ``n`` = number of cells): cell data in VTK order, x varying fastest:
  (nz, ny, nx[, components]) in 3D, (ny, nx[, components]) in 2D, or the same flattened to
  (n[, components]).  ``grid_shape``, ``origin`` and ``spacing`` are given in x, y, z order;
  ``origin`` is the lower corner of the grid (not the first cell centre).
"""

from __future__ import annotations

import errno
import os
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from time import perf_counter
from typing import BinaryIO, Iterator

import numpy as np

from simcli.errors import OutputError

KINDS = ("particles", "tets", "triangles", "lines", "grid")
NODES_PER_CELL = {"tets": 4, "triangles": 3, "lines": 2}
FORMATS = ("hdf5", "vtk")


@dataclass
class EntityMeta:
    """Static description of one output entity.

    ``fields`` maps a field name to ``(components, unit)`` or ``(components, unit, dtype)``;
    the dtype defaults to ``EntityMeta.dtype`` (float32) for every field.
    """

    name: str
    kind: str  # "particles" | "tets" | "triangles" | "lines" | "grid"
    n: int  # points (or for grids: cells) count
    dim: int  # 2 or 3
    fields: dict[str, tuple] = field(default_factory=dict)
    cells: np.ndarray | None = None  # static topology (n_cells, nodes per cell) for meshes
    grid_shape: tuple | None = None  # (nx, ny[, nz]) for kind "grid"
    origin: tuple | None = None  # lower corner, x y z order
    spacing: tuple | None = None  # cell size, x y z order
    dtype: str = "float32"  # default storage type of the fields
    cell_fields: tuple = ()  # names in ``fields`` given per cell (n_cells values) of a mesh, not per point

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"entity {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        if int(self.n) < 1:
            raise ValueError(f"entity {self.name!r}: n must be >= 1, got {self.n!r}")
        self.n = int(self.n)
        if self.dim not in (2, 3):
            raise ValueError(f"entity {self.name!r}: dim must be 2 or 3, got {self.dim!r}")
        if not self.name or "/" in self.name or self.name.startswith("."):
            raise ValueError(f"entity name {self.name!r} is not usable as a group / file name")
        norm: dict[str, tuple[int, str, str]] = {}
        for fname, spec in self.fields.items():
            if isinstance(spec, int):
                spec = (spec, "1")
            comps, unit = int(spec[0]), str(spec[1])
            dtype = str(np.dtype(spec[2] if len(spec) > 2 else self.dtype))
            if comps < 1:
                raise ValueError(f"entity {self.name!r}: field {fname!r} needs >= 1 component")
            norm[fname] = (comps, unit, dtype)
        self.fields = norm  # type: ignore[assignment]
        if self.kind == "grid":
            if self.grid_shape is None or len(self.grid_shape) != self.dim:
                raise ValueError(
                    f"grid entity {self.name!r}: grid_shape needs {self.dim} entries (x, y[, z])"
                )
            self.grid_shape = tuple(int(s) for s in self.grid_shape)
            if int(np.prod(self.grid_shape)) != self.n:
                raise ValueError(
                    f"grid entity {self.name!r}: n={self.n} but grid_shape {self.grid_shape} has "
                    f"{int(np.prod(self.grid_shape))} cells"
                )
            self.origin = tuple(float(v) for v in (self.origin or (0.0,) * self.dim))
            self.spacing = tuple(float(v) for v in (self.spacing or (1.0,) * self.dim))
            if len(self.origin) != self.dim or len(self.spacing) != self.dim:
                raise ValueError(f"grid entity {self.name!r}: origin and spacing need {self.dim} entries")
        else:
            if "position" not in self.fields:
                raise ValueError(f"entity {self.name!r}: a {self.kind} entity needs a 'position' field")
            if self.fields["position"][0] != self.dim:
                raise ValueError(f"entity {self.name!r}: position must have {self.dim} components")
        self.cell_fields = tuple(self.cell_fields)
        for fname in self.cell_fields:
            if fname not in self.fields or fname == "position" or self.kind not in NODES_PER_CELL:
                raise ValueError(
                    f"entity {self.name!r}: cell field {fname!r} needs a declared field of a mesh"
                )
        if self.kind in NODES_PER_CELL:
            if self.cells is None:
                raise ValueError(f"mesh entity {self.name!r} ({self.kind}) needs cells")
            cells = np.ascontiguousarray(self.cells, dtype=np.int64)
            npc = NODES_PER_CELL[self.kind]
            if cells.ndim != 2 or cells.shape[1] != npc:
                raise ValueError(
                    f"entity {self.name!r}: cells must have shape (n_cells, {npc}), got {cells.shape}"
                )
            if cells.size and (cells.min() < 0 or cells.max() >= self.n):
                raise ValueError(f"entity {self.name!r}: cells index outside 0..{self.n - 1}")
            self.cells = cells

    # -- shapes ---------------------------------------------------------------------------
    @property
    def zyx_shape(self) -> tuple[int, ...]:
        """Grid shape in storage order: (nz, ny, nx) or (ny, nx)."""
        assert self.grid_shape is not None
        return tuple(reversed(self.grid_shape))

    def _rows(self, fname: str) -> int:
        """Values per frame of a mesh or particle field: one per cell for cell fields, else one per point."""
        return int(self.cells.shape[0]) if fname in self.cell_fields else self.n

    def frame_shape(self, fname: str) -> tuple[int, ...]:
        """Shape of one frame of a field as stored (without the leading frame axis)."""
        comps = self.fields[fname][0]
        base = self.zyx_shape if self.kind == "grid" else (self._rows(fname),)
        return base + ((comps,) if comps > 1 else ())

    def prepare(self, fname: str, arr) -> np.ndarray:
        """Validate one field array of a frame; return it C-contiguous in storage shape/dtype."""
        comps, _unit, dtype = self.fields[fname]
        a = np.asarray(arr)
        want = self.frame_shape(fname)
        if a.shape != want:
            rows = self.n if self.kind == "grid" else self._rows(fname)
            flat = (rows,) + ((comps,) if comps > 1 else ())
            ok = a.size == int(np.prod(want)) and (
                a.shape == flat
                or (self.kind != "grid" and a.shape[:1] == (rows,))  # (n, 1) scalars, (n, 3, 3) tensors
            )
            if not ok:
                hint = " (grids are stored z, y, x: x varies fastest)" if self.kind == "grid" else ""
                raise ValueError(
                    f"entity {self.name!r} field {fname!r}: expected shape {want} or {flat}, "
                    f"got {a.shape}{hint}"
                )
            a = a.reshape(want)
        return np.ascontiguousarray(a, dtype=dtype)


# -- shared helpers ------------------------------------------------------------------------


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


# -- the sink ------------------------------------------------------------------------------


class FrameSink:
    """Writes every frame to the enabled formats (``"hdf5"``: sim.h5 + sim.xdmf; ``"vtk"``).

    Usage::

        sink = FrameSink(out_dir, ["hdf5", "vtk"])
        sink.open(entities, scene_text, attrs)            # or resume_frame=k to append from frame k
        sink.write_frame(0, 0, 0.0, {"jelly": {"position": x, "velocity": v}})
        ...
        sink.close()

    ``seconds`` holds the wall time spent per format (for run.json).
    """

    def __init__(self, out_dir: Path, formats: list[str]):
        self.out_dir = Path(out_dir)
        unknown = [f for f in formats if f not in FORMATS]
        if unknown:
            raise ValueError(f"unknown output format(s) {unknown}; known: {list(FORMATS)}")
        self.formats = list(dict.fromkeys(formats))
        self.entities: list[EntityMeta] = []
        self.colliders: dict[str, int] = {}
        self.next_frame = 0
        self.seconds: dict[str, float] = {f: 0.0 for f in self.formats}
        self._h5 = None
        self._xdmf = None
        self._vtk = None
        self._open = False

    # context manager ------------------------------------------------------------------
    def __enter__(self) -> "FrameSink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def h5_path(self) -> Path:
        return self.out_dir / "sim.h5"

    def open(
        self,
        entities: list[EntityMeta],
        scene_text: str,
        attrs: dict | None = None,
        resume_frame: int | None = None,
        colliders: dict[str, int] | None = None,
    ) -> None:
        """``colliders``: named collider -> dim, for sim.h5 /colliders/<name>/force (dim components) and
        /torque (3 in 3D, 1 in 2D) per frame."""
        self.colliders = dict(colliders or {})
        names = [e.name for e in entities]
        if len(set(names)) != len(names):
            raise ValueError(f"entity names must be unique, got {names}")
        if resume_frame is not None and resume_frame < 0:
            raise ValueError("resume_frame must be >= 0")
        self.entities = list(entities)
        ensure_dir(self.out_dir)
        try:
            t0 = perf_counter()
            if "hdf5" in self.formats:
                from .hdf5 import H5Writer
                from .xdmf import XdmfWriter

                self._h5 = H5Writer(self.h5_path)
                self._h5.open(self.entities, scene_text, attrs or {}, resume_frame, colliders=self.colliders)
                self._xdmf = XdmfWriter(self.out_dir / "sim.xdmf", self.h5_path.name, self.entities)
                self._xdmf.reset(self._h5.times())
                t1 = perf_counter()
                self.seconds["hdf5"] += t1 - t0
                t0 = t1
            if "vtk" in self.formats:
                from .vtk import VtkWriter

                self._vtk = VtkWriter(self.out_dir / "vtk", self.entities)
                self._vtk.open(resume_frame)
                self.seconds["vtk"] += perf_counter() - t0
        except BaseException:
            try:
                self.close()
            except OutputError:
                pass
            raise
        self.next_frame = resume_frame or 0
        self._open = True

    def write_frame(
        self,
        frame: int,
        step: int,
        time: float,
        data: dict[str, dict[str, np.ndarray]],
        colliders: dict[str, dict[str, np.ndarray]] | None = None,
    ) -> None:
        """``colliders``: named collider -> {"force", "torque"} (see ``open``)."""
        if not self._open:
            raise RuntimeError("FrameSink.write_frame before open()")
        if frame != self.next_frame:
            raise ValueError(
                f"frames must be written in order: expected frame {self.next_frame}, got {frame}"
            )
        prepared = self._prepare(data)
        t = float(time)
        t0 = perf_counter()
        if self._h5 is not None:
            self._h5.write_frame(frame, int(step), t, prepared, colliders=colliders)
            self._xdmf.add_frame(frame, t)
            t1 = perf_counter()
            self.seconds["hdf5"] += t1 - t0
            t0 = t1
        if self._vtk is not None:
            self._vtk.write_frame(frame, t, prepared)
            self.seconds["vtk"] += perf_counter() - t0
        self.next_frame = frame + 1

    def _prepare(self, data: dict) -> dict[str, dict[str, np.ndarray]]:
        out = {}
        for e in self.entities:
            if e.name not in data:
                raise ValueError(f"write_frame: no data for entity {e.name!r}")
            ed = data[e.name]
            missing = [f for f in e.fields if f not in ed]
            extra = [f for f in ed if f not in e.fields]
            if missing or extra:
                raise ValueError(
                    f"write_frame: entity {e.name!r}: missing fields {missing}, undeclared fields {extra}"
                )
            out[e.name] = {f: e.prepare(f, ed[f]) for f in e.fields}
        return out

    def abort(self) -> None:
        """Close after a failure elsewhere (numerical, a signal, a write error): what can be closed is,
        sim.h5 is abandoned if it cannot be (see ``H5Writer.abandon``); never raises."""
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass
        h5, self._h5 = self._h5, None
        if h5 is not None:
            h5.abandon()

    def close(self) -> None:
        errors = []
        for w in (self._h5, self._vtk):
            if w is not None:
                try:
                    w.close()
                except OutputError as exc:
                    errors.append(exc)
                except Exception as exc:  # noqa: BLE001 - h5py's own errors on close
                    if hasattr(w, "abandon"):
                        w.abandon()
                    errors.append(output_error(getattr(w, "path", self.out_dir), exc, "close"))
        self._h5 = self._vtk = self._xdmf = None
        self._open = False
        if errors:
            raise errors[0]
