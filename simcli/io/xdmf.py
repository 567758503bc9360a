"""``sim.xdmf``: an XDMF description of sim.h5 that ParaView / VTK open directly, with either of
VTK's XDMF readers: the XDMF 3 reader ParaView picks by default (vtkXdmf3Reader, "Xdmf3ReaderS/T")
and the legacy XDMF 2 one (vtkXdmfReader, ParaView's "XDMF Reader").

One temporal collection per entity; each frame is a uniform grid whose geometry and attributes
are frame ``i`` of the frame-indexed datasets in sim.h5 (the layout the contract describes; the
file is written in SWMR mode, which cannot add a dataset per frame). Particles use Polyvertex
topology, meshes Tetrahedron / Triangle / Polyline topology on the static ``cells`` dataset,
grids 3DCoRectMesh with cell-centred attributes (a 2D grid as one layer of 3D cells centred on
z = 0: VTK's XDMF reader misplaces a 2DCoRectMesh and its cell data).

How one frame of a dataset is addressed, so that both readers read it (see :func:`_heavy`):

* the XDMF 2 reader reads a hyperslab DataItem (two child DataItems: start/stride/count, then
  the dataset). It accepts the XDMF 1 spelling ``Type="HyperSlab"`` for ``ItemType``.
* the XDMF 3 library reads ``ItemType="HyperSlab"`` (and ``ItemType="Function"``) as a
  reference that VTK's XDMF 3 reader asks for its number type before reading it: the array is
  skipped ("Skipping unrecognized array type [None]") and the grid has 0 points. It does not
  know the XDMF 1 ``Type`` spelling, so the same element is for it a plain HDF DataItem whose
  text is XDMF 3's own hyperslab syntax ``file:/dataset|start:stride:count:dataspace``, read
  lazily (only the frame shown). (An XDMF 3 ``<Function>`` wrapper also works but reads every
  frame of every field when the file is opened: minutes and the whole of sim.h5 in memory.)

Names (entities, fields) are XML-escaped wherever they are written (attribute or text).

The file is rewritten atomically after each frame so that it always lists exactly the frames
that sim.h5 holds.  Per-frame XML is built once and cached, so a rewrite is a join + write.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from .atomic import atomic_write_text

if TYPE_CHECKING:  # pragma: no cover
    from .meta import EntityMeta

TOPOLOGY = {"tets": "Tetrahedron", "triangles": "Triangle", "lines": "Polyline"}


def _number_type(dtype: str) -> tuple[str, int]:
    dt = np.dtype(dtype)
    kind = {"f": "Float", "i": "Int", "u": "UInt", "b": "UChar"}[dt.kind]
    if kind == "Int" and dt.itemsize == 1:
        kind = "Char"
    return kind, dt.itemsize


def _attribute_type(comps: int, dim: int) -> str:
    if comps == 1:
        return "Scalar"
    if comps == 3 or (comps == 2 and dim == 2):
        return "Vector"
    if comps == 6:
        return "Tensor6"
    if comps == 9:
        return "Tensor"
    return "Matrix"


def _fmt(x: float) -> str:
    return repr(float(x))


def _ints(v) -> str:
    return " ".join(str(int(x)) for x in v)


def _heavy(path: str, dtype: str, dims, full, start, count) -> str:
    """A DataItem for ``path[start : start + count]`` (stride 1) of an HDF5 dataset of shape ``full``,
    shaped ``dims``: an XDMF 2 hyperslab (``Type=``) whose own text is the XDMF 3 hyperslab syntax."""
    nt, prec = _number_type(dtype)
    rank = len(full)
    stride = (1,) * rank
    xdmf3 = f"{path}|{_ints(start)}:{_ints(stride)}:{_ints(count)}:{_ints(full)}"
    return (
        f'<DataItem Type="HyperSlab" Dimensions="{_ints(dims)}" NumberType="{nt}" Precision="{prec}" '
        f'Format="HDF">{escape(xdmf3)}'
        f'<DataItem Dimensions="3 {rank}" NumberType="UInt" Format="XML">'
        f"{_ints(start)} {_ints(stride)} {_ints(count)}</DataItem>"
        f'<DataItem Dimensions="{_ints(full)}" NumberType="{nt}" Precision="{prec}" Format="HDF">'
        f"{escape(path)}</DataItem></DataItem>"
    )


class XdmfWriter:
    def __init__(self, path: Path, h5_name: str, entities: list[EntityMeta]):
        self.path = Path(path)
        self.h5 = h5_name
        self.entities = list(entities)
        self._frames: list[str] = []  # per-frame XML per entity, in entity order
        self._nframes = 0

    def reset(self, times: list[float], counts: list[dict] | None = None) -> None:
        """Start over with the frames already in sim.h5 (fresh: none; resume: 0..k-1); ``counts``: per frame,
        the live count of each entity whose count varies."""
        counts = counts or [{} for _ in times]
        self._frames = [
            [self._grid(e, i, t, c.get(e.name)) for e in self.entities]
            for i, (t, c) in enumerate(zip(times, counts))
        ]
        self._write()

    def add_frame(self, frame: int, time: float, counts: dict | None = None) -> None:
        assert frame == len(self._frames)
        counts = counts or {}
        self._frames.append([self._grid(e, frame, time, counts.get(e.name)) for e in self.entities])
        self._write()

    # ------------------------------------------------------------------------------------
    def _slab(self, e: EntityMeta, fname: str, frame: int, rows: int | None = None) -> str:
        """Frame ``frame`` of /entities/<e>/<fname>, readable by both XDMF readers (module doc); ``rows``:
        only
        the first rows (the live particles of an entity whose count varies)."""
        dtype = e.fields[fname][2]
        shape = e.frame_shape(fname)
        if rows is not None:
            full = (frame + 1,) + shape
            part = (rows,) + shape[1:]
            start = (frame,) + (0,) * len(shape)
            return _heavy(f"{self.h5}:/entities/{e.name}/{fname}", dtype, part, full, start, (1,) + part)
        dims = shape
        if e.kind == "grid" and e.dim == 2:
            dims = (1,) + shape  # the one-layer 3D mesh of a 2D grid
        full = (frame + 1,) + shape  # any first dimension > frame works; keep it honest and small
        start = (frame,) + (0,) * len(shape)
        count = (1,) + shape
        return _heavy(f"{self.h5}:/entities/{e.name}/{fname}", dtype, dims, full, start, count)

    def _grid(self, e: EntityMeta, frame: int, time: float, rows: int | None = None) -> str:
        name = quoteattr(f"{e.name}_{frame:06d}")
        parts = [f'<Grid Name={name} GridType="Uniform"><Time Value="{_fmt(time)}"/>']
        center = "Node"
        if e.kind == "grid":
            center = "Cell"
            # A 2D grid is written as one layer of 3D cells, one cell thick and centred on z = 0:
            # VTK's XDMF (2) reader puts a 2DCoRectMesh in the y-z plane with x and y swapped,
            # and reads no cell data from a mesh that is one point thick.
            if e.dim == 3:
                zyx, org, spc = e.zyx_shape, list(reversed(e.origin)), list(reversed(e.spacing))
            else:
                dz = min(e.spacing)
                zyx = (1,) + e.zyx_shape
                org = [-0.5 * dz] + list(reversed(e.origin))  # z y x order
                spc = [dz] + list(reversed(e.spacing))
            pts = " ".join(str(s + 1) for s in zyx)
            parts.append(f'<Topology TopologyType="3DCoRectMesh" Dimensions="{pts}"/>')
            parts.append(
                '<Geometry GeometryType="ORIGIN_DXDYDZ">'
                f'<DataItem Dimensions="3" NumberType="Float" Precision="8" Format="XML">'
                f"{' '.join(_fmt(v) for v in org)}</DataItem>"
                f'<DataItem Dimensions="3" NumberType="Float" Precision="8" Format="XML">'
                f"{' '.join(_fmt(v) for v in spc)}</DataItem>"
                "</Geometry>"
            )
        else:
            if e.kind == "particles":
                # connectivity from the static /vertices (0..n-1), a whole-array hyperslab as the cells
                # below: without it the XDMF 3 reader makes points but no cells
                nv = e.n if rows is None else rows
                verts = _heavy(f"{self.h5}:/entities/{e.name}/vertices", "int64", (nv,), (e.n,), (0,), (nv,))
                parts.append(
                    f'<Topology TopologyType="Polyvertex" NumberOfElements="{nv}" NodesPerElement="1">'
                    f"{verts}</Topology>"
                )
            else:
                nc, npc = e.cells.shape
                extra = f' NodesPerElement="{npc}"' if e.kind == "lines" else ""
                # The cells are a whole-array hyperslab, as the frames' data: vtkXdmfReader caches
                # a mesh keyed on the DataItem text, and a plain DataItem here (the same text in
                # every frame) served stale points; the tests read frames out of order to catch it.
                cells = _heavy(
                    f"{self.h5}:/entities/{e.name}/cells", "int64", (nc, npc), (nc, npc), (0, 0), (nc, npc)
                )
                parts.append(
                    f'<Topology TopologyType="{TOPOLOGY[e.kind]}" NumberOfElements="{nc}"{extra}>'
                    f"{cells}</Topology>"
                )
            parts.append(f'<Geometry GeometryType="{"XYZ" if e.dim == 3 else "XY"}">')
            parts.append(self._slab(e, "position", frame, rows))
            parts.append("</Geometry>")
        for fname, (comps, _unit, _dt) in e.fields.items():
            if fname == "position" and e.kind != "grid":
                continue
            c = "Cell" if fname in e.cell_fields else center
            parts.append(
                f'<Attribute Name={quoteattr(fname)} AttributeType="{_attribute_type(comps, e.dim)}" '
                f'Center="{c}">{self._slab(e, fname, frame, rows)}</Attribute>'
            )
        parts.append("</Grid>")
        return "".join(parts)

    def _write(self) -> None:
        out = ['<?xml version="1.0" ?>\n<Xdmf Version="3.0">\n<Domain>\n']
        for j, e in enumerate(self.entities):
            out.append(f'<Grid Name={quoteattr(e.name)} GridType="Collection" CollectionType="Temporal">\n')
            for fr in self._frames:
                out.append(fr[j])
                out.append("\n")
            out.append("</Grid>\n")
        out.append("</Domain>\n</Xdmf>\n")
        atomic_write_text(self.path, "".join(out))
