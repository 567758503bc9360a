"""The ``FrameSink`` that fans frames out to the writers; the entity descriptions (``meta.py``) and the
atomic-file helpers (``atomic.py``) it shares with the writers are re-exported here.

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

from pathlib import Path
from time import perf_counter

import numpy as np

from simcli.errors import OutputError

# re-exported: the writers import these from their own leaf modules, so none of them imports this one
from .atomic import (  # noqa: F401
    atomic_file,
    atomic_write_bytes,
    atomic_write_text,
    ensure_dir,
    guard,
    output_error,
)
from .meta import KINDS, NODES_PER_CELL, EntityMeta  # noqa: F401

FORMATS = ("hdf5", "vtk")


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
        series: dict[str, tuple[int, str]] | None = None,
        series_until: float | None = None,
        colliders: dict[str, int] | None = None,
        frame_series: dict[str, str] | None = None,
    ) -> None:
        """``frame_series``: sim.h5 path -> unit of a scalar written with every frame (``values`` of
        write_frame: emitted and removed mass). ``series``: named time series (probes) written to sim.h5 as
        ``/probes/<name>/time`` and ``/value``
        by :meth:`write_series`, name -> (components, unit); on a resume their samples after time
        ``series_until`` are dropped. ``colliders``: named collider -> dim, for sim.h5
        /colliders/<name>/force (dim components) and /torque (3 in 3D, 1 in 2D) per frame."""
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
                self._h5.open(
                    self.entities,
                    scene_text,
                    attrs or {},
                    resume_frame,
                    series,
                    series_until,
                    colliders=self.colliders,
                    frame_series=frame_series,
                )
                self._xdmf = XdmfWriter(self.out_dir / "sim.xdmf", self.h5_path.name, self.entities)
                self._xdmf.reset(self._h5.times(), self._h5.counts())
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
        values: dict[str, float] | None = None,
    ) -> None:
        """``colliders``: named collider -> {"force", "torque"}; ``values``: the frame_series (see
        ``open``)."""
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
            self._h5.write_frame(frame, int(step), t, prepared, colliders=colliders, values=values)
            counts = {e.name: len(prepared[e.name]["position"]) for e in self.entities if e.variable}
            self._xdmf.add_frame(frame, t, counts)
            t1 = perf_counter()
            self.seconds["hdf5"] += t1 - t0
            t0 = t1
        if self._vtk is not None:
            self._vtk.write_frame(frame, t, prepared)
            self.seconds["vtk"] += perf_counter() - t0
        self.next_frame = frame + 1

    def write_series(self, samples: dict[str, list[tuple[float, np.ndarray]]], flush: bool = True) -> None:
        """Append samples, name -> [(time, value), ...] in time order, to the named series (sim.h5 only;
        nothing without hdf5 output); ``flush=False`` when write_frame comes next (it flushes them too)."""
        if self._h5 is not None:
            t0 = perf_counter()
            self._h5.write_series(samples, flush)
            self.seconds["hdf5"] += perf_counter() - t0

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
