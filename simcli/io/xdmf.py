"""``sim.xdmf``: an XDMF 3 description of sim.h5 that ParaView / VTK open directly.

One temporal collection per entity; each frame is a uniform grid whose geometry and
attributes are hyperslabs (frame ``i``) of the frame-indexed datasets in sim.h5.  Particles
use Polyvertex topology, meshes Tetrahedron / Triangle / Polyline topology on the static
``cells`` dataset, grids 3DCoRectMesh with cell-centred attributes (a 2D grid as one layer of 3D cells centred
on z = 0: VTK's XDMF reader misplaces a 2DCoRectMesh and its cell data).

The file is rewritten atomically after each frame so that it always lists exactly the frames
that sim.h5 holds.  Per-frame XML is built once and cached, so a rewrite is a join + write.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

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


class XdmfWriter:
    def __init__(self, path: Path, h5_name: str, entities: list[EntityMeta]):
        self.path = Path(path)
        self.h5 = h5_name
        self.entities = list(entities)
        self._frames: list[str] = []  # per-frame XML per entity, in entity order
        self._nframes = 0

    def reset(self, times: list[float]) -> None:
        """Start over with the frames already in sim.h5 (fresh: none; resume: 0..k-1)."""
        self._frames = [[self._grid(e, i, t) for e in self.entities] for i, t in enumerate(times)]
        self._write()

    def add_frame(self, frame: int, time: float) -> None:
        assert frame == len(self._frames)
        self._frames.append([self._grid(e, frame, time) for e in self.entities])
        self._write()

    # ------------------------------------------------------------------------------------
    def _slab(self, e: EntityMeta, fname: str, frame: int) -> str:
        """A hyperslab DataItem picking frame ``frame`` of /entities/<e>/<fname>."""
        comps, _unit, dtype = e.fields[fname]
        shape = e.frame_shape(fname)
        full = (frame + 1,) + shape  # any first dimension > frame works; keep it honest and small
        rank = len(full)
        start = " ".join([str(frame)] + ["0"] * (rank - 1))
        stride = " ".join(["1"] * rank)
        count = " ".join(["1"] + [str(s) for s in shape])
        nt, prec = _number_type(dtype)
        dims = " ".join(str(s) for s in shape)
        if e.kind == "grid" and e.dim == 2:
            dims = "1 " + dims  # the one-layer 3D mesh of a 2D grid
        fdims = " ".join(str(s) for s in full)
        return (
            f'<DataItem ItemType="HyperSlab" Dimensions="{dims}" Type="HyperSlab">'
            f'<DataItem Dimensions="3 {rank}" NumberType="UInt" Format="XML">'
            f"{start} {stride} {count}</DataItem>"
            f'<DataItem Dimensions="{fdims}" NumberType="{nt}" Precision="{prec}" Format="HDF">'
            f"{self.h5}:/entities/{e.name}/{fname}</DataItem></DataItem>"
        )

    def _grid(self, e: EntityMeta, frame: int, time: float) -> str:
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
                parts.append(
                    f'<Topology TopologyType="Polyvertex" NumberOfElements="{e.n}" NodesPerElement="1"/>'
                )
            else:
                nc, npc = e.cells.shape
                extra = f' NodesPerElement="{npc}"' if e.kind == "lines" else ""
                # The cells are wrapped in a whole-array hyperslab: vtkXdmfReader caches a mesh
                # keyed on the topology/geometry DataItem *text*, which would be the same for
                # every frame here and serve stale points; a wrapped DataItem has no text, so
                # that cache is (silently) off.
                parts.append(
                    f'<Topology TopologyType="{TOPOLOGY[e.kind]}" NumberOfElements="{nc}"{extra}>'
                    f'<DataItem ItemType="HyperSlab" Dimensions="{nc} {npc}" Type="HyperSlab">'
                    f'<DataItem Dimensions="3 2" NumberType="UInt" Format="XML">0 0 1 1 {nc} {npc}</DataItem>'
                    f'<DataItem Dimensions="{nc} {npc}" NumberType="Int" Precision="8" Format="HDF">'
                    f"{self.h5}:/entities/{e.name}/cells</DataItem></DataItem></Topology>"
                )
            parts.append(f'<Geometry GeometryType="{"XYZ" if e.dim == 3 else "XY"}">')
            parts.append(self._slab(e, "position", frame))
            parts.append("</Geometry>")
        for fname, (comps, _unit, _dt) in e.fields.items():
            if fname == "position" and e.kind != "grid":
                continue
            c = "Cell" if fname in e.cell_fields else center
            parts.append(
                f'<Attribute Name={quoteattr(fname)} AttributeType="{_attribute_type(comps, e.dim)}" '
                f'Center="{c}">{self._slab(e, fname, frame)}</Attribute>'
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
