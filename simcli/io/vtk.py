"""Per-frame VTK XML files and one ParaView collection (.pvd) per entity.

``OUT/vtk/<entity>/<entity>_000042.vtu`` (particles as vertex cells, tets, triangles, lines)
or ``.vti`` (grids, cell data), binary, zlib-compressed, appended raw data (the fastest
layout VTK reads), written to a temporary name and renamed; then ``OUT/vtk/<entity>.pvd`` is
rewritten atomically, so after a crash it lists only files that exist (a SIGKILL between the
two renames leaves the newest file unlisted; the next open, fresh or resumed, removes it).

Written directly (no meshio / vtk dependency at run time); meshio and VTK read the files.
"""

from __future__ import annotations

import os
import re
import struct
import sys
import xml.etree.ElementTree as ET
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

import numpy as np

from .atomic import atomic_write_bytes, atomic_write_text, ensure_dir, guard

if TYPE_CHECKING:  # pragma: no cover
    from .meta import EntityMeta

# zlib level: float data barely compresses further at higher levels, which cost 2-10x the time
COMPRESSION_LEVEL = 1
VTK_CELL_TYPE = {"particles": 1, "lines": 3, "triangles": 5, "tets": 10}  # VERTEX, LINE, TRIANGLE, TETRA
VTK_TYPE = {
    "float32": "Float32",
    "float64": "Float64",
    "int8": "Int8",
    "uint8": "UInt8",
    "int16": "Int16",
    "uint16": "UInt16",
    "int32": "Int32",
    "uint32": "UInt32",
    "int64": "Int64",
    "uint64": "UInt64",
    "bool": "UInt8",
}


class _Compressor:
    """zlib-compresses arrays into VTK's compressed-block layout, blocks in parallel threads
    (zlib releases the GIL)."""

    BLOCK = 1 << 18  # uncompressed bytes per block

    def __init__(self, level: int, threads: int | None = None):
        self.level = level
        if threads is None:
            threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        self.threads = min(4, threads or 1)
        self._pool: ThreadPoolExecutor | None = None

    def _map(self, chunks: list) -> list[bytes]:
        if self.threads > 1 and len(chunks) > 1 and sum(len(c) for c in chunks) > (256 << 10):
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="simcli-vtk")
            return list(self._pool.map(lambda c: zlib.compress(c, self.level), chunks))
        return [zlib.compress(c, self.level) for c in chunks]

    def blocks(self, arrays: list[np.ndarray]) -> list[bytes]:
        """One appended-data block per array: UInt64 header [nblocks, block, last, csizes...] + data."""
        views, spans = [], []
        for a in arrays:
            a = np.ascontiguousarray(a)
            if a.dtype == np.bool_:
                a = a.view(np.uint8)
            mv = memoryview(a.reshape(-1)).cast("B")  # little-endian on every platform we run on
            parts = [mv[i : i + self.BLOCK] for i in range(0, len(mv), self.BLOCK)] or [mv[:0]]
            spans.append((len(views), len(parts), len(mv)))
            views.extend(parts)
        comp = self._map(views)
        out = []
        for start, k, nbytes in spans:
            cs = comp[start : start + k]
            last = nbytes - (k - 1) * self.BLOCK
            head = struct.pack(f"<{3 + k}Q", k, min(self.BLOCK, nbytes), last, *(len(c) for c in cs))
            out.append(b"".join([head, *cs]))
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


class _EntityFiles:
    """Frame files and the .pvd of one entity."""

    def __init__(self, root: Path, e: EntityMeta, comp: _Compressor):
        self.e = e
        self.comp = comp
        self.dir = root / e.name
        self.pvd = root / f"{e.name}.pvd"
        self.ext = "vti" if e.kind == "grid" else "vtu"
        self.entries: list[tuple[int, float, str]] = []  # (frame, time, relative file)
        self._static: list[tuple[str, bytes, str]] | None = None  # compressed cells of a vtu

    def fname(self, frame: int) -> str:
        return f"{self.e.name}_{frame:06d}.{self.ext}"

    # -- open / resume ------------------------------------------------------------------
    def open(self, resume_frame: int | None) -> None:
        ensure_dir(self.dir)
        pat = re.compile(rf"^{re.escape(self.e.name)}_(\d+)\.(vtu|vti)$")
        kept: dict[int, float] = {}
        if resume_frame is not None and self.pvd.exists():
            try:
                root = ET.parse(self.pvd).getroot()
                for ds in root.iter("DataSet"):
                    m = pat.match(Path(ds.get("file", "")).name)
                    if m and int(m.group(1)) < resume_frame:
                        kept[int(m.group(1))] = float(ds.get("timestep", "nan"))
            except (ET.ParseError, ValueError):
                kept = {}
        limit = resume_frame if resume_frame is not None else 0
        with guard(self.dir, "clean"):
            for p in self.dir.iterdir():
                m = pat.match(p.name)
                if m:
                    if int(m.group(1)) >= limit:
                        p.unlink()
                elif p.name.startswith(".") and p.name.endswith(".tmp"):
                    p.unlink()  # left by a killed writer
        self.entries = [
            (fr, t, f"{self.e.name}/{self.fname(fr)}")
            for fr, t in sorted(kept.items())
            if (self.dir / self.fname(fr)).exists()
        ]
        self.write_pvd()

    def write_pvd(self) -> None:
        lines = [
            '<?xml version="1.0"?>\n'
            '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n<Collection>\n'
        ]
        for _fr, t, f in self.entries:
            lines.append(f'<DataSet timestep="{repr(float(t))}" group="" part="0" file={quoteattr(f)}/>\n')
        lines.append("</Collection>\n</VTKFile>\n")
        atomic_write_text(self.pvd, "".join(lines))

    # -- frames ---------------------------------------------------------------------------
    def write_frame(self, frame: int, time: float, data: dict[str, np.ndarray]) -> None:
        body = self._vti(data) if self.e.kind == "grid" else self._vtu(data)
        path = self.dir / self.fname(frame)
        atomic_write_bytes(path, body)
        self.entries = [x for x in self.entries if x[0] != frame]
        self.entries.append((frame, time, f"{self.e.name}/{self.fname(frame)}"))
        self.write_pvd()

    def _point_arrays(
        self, data: dict[str, np.ndarray], cell: bool = False
    ) -> list[tuple[str, np.ndarray, int]]:
        """Point data arrays (cell=False) or the per-cell fields of a mesh (cell=True)."""
        out = []
        for fname, (comps, _u, _dt) in self.e.fields.items():
            if fname == "position" and self.e.kind != "grid":
                continue
            if (fname in self.e.cell_fields) != cell:
                continue
            a = data[fname]
            if self.e.kind != "grid":
                rows = self.e.frame_shape(fname)[0] if not self.e.variable else len(data["position"])
                a = a.reshape(rows, comps) if comps > 1 else a.reshape(rows)
            if comps == 2 and self.e.dim == 2:  # 2D vectors as 3D so ParaView glyphs them
                a = np.concatenate([a, np.zeros(a.shape[:-1] + (1,), a.dtype)], axis=-1)
                comps = 3
            out.append((fname, a, comps))
        return out

    def _body(self, head: str, sections: list[tuple[str, list[tuple]]], tail: str) -> list[bytes]:
        """File content: XML header with one DataArray per array, then the appended raw blocks.

        ``sections``: (xml tag, [(name, array or precompressed block, components)]).
        """
        arrays = [a for _tag, items in sections for _n, a, _c in items]
        todo = [a for a in arrays if isinstance(a, np.ndarray)]
        done = iter(self.comp.blocks(todo))
        blocks = [a if isinstance(a, bytes) else next(done) for a in arrays]
        xml, off, i = [head], 0, 0
        for tag, items in sections:
            xml.append(f"<{tag}>")
            for name, a, comps in items:
                t = VTK_TYPE[str(a.dtype)] if isinstance(a, np.ndarray) else comps  # static: comps = type
                nc = f' NumberOfComponents="{comps}"' if isinstance(a, np.ndarray) and comps > 1 else ""
                xml.append(
                    f'<DataArray type="{t}" Name={quoteattr(name)}{nc} format="appended" offset="{off}"/>'
                )
                off += len(blocks[i])
                i += 1
            xml.append(f"</{tag}>")
        xml.append(tail)
        return [
            "".join(xml).encode(),
            b'<AppendedData encoding="raw">\n_',
            *blocks,
            b"\n</AppendedData>\n</VTKFile>\n",
        ]

    def _vtu(self, data: dict[str, np.ndarray]) -> list[bytes]:
        e = self.e
        n = len(data["position"])
        if e.variable and n != getattr(self, "_n_static", None):  # a varying count: its own vertex cells
            self._static, self._n_static = None, n
        if self._static is None:  # topology never changes: compress it once
            if e.kind == "particles" and e.variable:
                conn = np.arange(n, dtype=np.int64)
                npc, ncell = 1, n
            elif e.kind == "particles":
                conn = np.arange(e.n, dtype=np.int64)
                npc, ncell = 1, e.n
            else:
                conn = e.cells.reshape(-1)
                ncell, npc = e.cells.shape
            offs = np.arange(1, ncell + 1, dtype=np.int64) * npc
            types = np.full(ncell, VTK_CELL_TYPE[e.kind], dtype=np.uint8)
            b = self.comp.blocks([conn, offs, types])
            self._static = [
                ("connectivity", b[0], "Int64"),
                ("offsets", b[1], "Int64"),
                ("types", b[2], "UInt8"),
            ]
            self._ncell = ncell
        pos = data["position"]
        if e.dim == 2:
            pos = np.concatenate([pos, np.zeros((len(pos), 1), pos.dtype)], axis=1)
        head = (
            '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
            'header_type="UInt64" compressor="vtkZLibDataCompressor">\n<UnstructuredGrid>\n'
            f'<Piece NumberOfPoints="{len(pos)}" NumberOfCells="{self._ncell}">'
        )
        sections = [("PointData", self._point_arrays(data))]
        if e.cell_fields:
            sections.append(("CellData", self._point_arrays(data, cell=True)))
        sections += [("Points", [("Points", pos, 3)]), ("Cells", self._static)]
        return self._body(head, sections, "</Piece>\n</UnstructuredGrid>\n")

    def _vti(self, data: dict[str, np.ndarray]) -> list[bytes]:
        e = self.e
        shape = list(e.grid_shape) + [0] * (3 - e.dim)
        origin = list(e.origin) + [0.0] * (3 - e.dim)
        spacing = list(e.spacing) + [1.0] * (3 - e.dim)
        ext = " ".join(f"0 {s}" for s in shape)
        head = (
            '<?xml version="1.0"?>\n<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian" '
            'header_type="UInt64" compressor="vtkZLibDataCompressor">\n'
            f'<ImageData WholeExtent="{ext}" Origin="{" ".join(map(repr, origin))}" '
            f'Spacing="{" ".join(map(repr, spacing))}">\n<Piece Extent="{ext}">'
        )
        return self._body(head, [("CellData", self._point_arrays(data))], "</Piece>\n</ImageData>\n")


class VtkWriter:
    """Writes OUT/vtk/; used by :class:`simcli.io.frames.FrameSink`."""

    def __init__(
        self,
        root: Path,
        entities: list[EntityMeta],
        level: int = COMPRESSION_LEVEL,
        threads: int | None = None,
    ):
        self.root = Path(root)
        self.comp = _Compressor(level, threads)
        self.files = [_EntityFiles(self.root, e, self.comp) for e in entities]

    def open(self, resume_frame: int | None) -> None:
        ensure_dir(self.root)
        for f in self.files:
            f.open(resume_frame)

    def write_frame(self, frame: int, time: float, data: dict[str, dict[str, np.ndarray]]) -> None:
        for f in self.files:
            f.write_frame(frame, time, data[f.e.name])

    def close(self) -> None:
        self.comp.close()


if sys.byteorder != "little":  # pragma: no cover
    raise ImportError("simcli.io.vtk writes little-endian data and needs a little-endian machine")
