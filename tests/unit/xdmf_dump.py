"""Read a sim.xdmf with one of VTK's XDMF readers and print what it gives, as JSON on stdout.

    python xdmf_dump.py vtkXdmf3Reader|vtkXdmfReader OUT/sim.xdmf [frame ...]

Run as a separate process by tests/unit/test_xdmf_readers.py, with any Python whose ``vtkmodules``
has the reader (pip VTK has only the XDMF 2 one; Debian's python3-paraview has both), so that
the test suite's own VTK is not needed to check ParaView's default (XDMF 3) reader. For each
frame asked (default: all, last first, so that nothing can come from a stale cache): per block
(entity), the number of points and cells, the VTK cell types, the points and every point and
cell array, as lists.
"""

from __future__ import annotations

import json
import sys


def _dataset(o) -> dict:
    from vtkmodules.util.numpy_support import vtk_to_numpy

    d = {"class": o.GetClassName(), "points": o.GetNumberOfPoints(), "cells": o.GetNumberOfCells()}
    d["cell_types"] = sorted({o.GetCellType(i) for i in range(o.GetNumberOfCells())})
    if hasattr(o, "GetPoints") and o.GetPoints() is not None:
        d["xyz"] = vtk_to_numpy(o.GetPoints().GetData()).tolist()
    if hasattr(o, "GetDimensions"):
        d["dimensions"] = list(o.GetDimensions())
        d["origin"] = list(o.GetOrigin())
        d["spacing"] = list(o.GetSpacing())
    if o.GetNumberOfCells() and hasattr(o, "GetCellPoints") and not hasattr(o, "GetDimensions"):
        from vtkmodules.vtkCommonCore import vtkIdList

        ids = vtkIdList()
        conn = []
        for i in range(o.GetNumberOfCells()):
            o.GetCellPoints(i, ids)
            conn.append([ids.GetId(j) for j in range(ids.GetNumberOfIds())])
        d["connectivity"] = conn
    for key, data in (("point_data", o.GetPointData()), ("cell_data", o.GetCellData())):
        d[key] = {
            data.GetArrayName(i): vtk_to_numpy(data.GetArray(i)).tolist()
            for i in range(data.GetNumberOfArrays())
        }
    return d


def _blocks(o, name: str, out: dict) -> None:
    from vtkmodules.vtkCommonDataModel import vtkCompositeDataSet

    if o is None:
        out[name] = None
    elif o.IsA("vtkDataSet"):
        out[name] = _dataset(o)
    else:
        for i in range(o.GetNumberOfBlocks()):
            md = o.GetMetaData(i) if o.HasMetaData(i) else None
            sub = md.Get(vtkCompositeDataSet.NAME()) if md is not None else None
            _blocks(o.GetBlock(i), sub or f"{name}/{i}", out)


def main() -> None:
    reader_name, path = sys.argv[1], sys.argv[2]
    if reader_name == "vtkXdmf3Reader":
        from vtkmodules.vtkIOXdmf3 import vtkXdmf3Reader as cls
    else:
        from vtkmodules.vtkIOXdmf2 import vtkXdmfReader as cls
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

    r = cls()
    r.SetFileName(path)
    r.UpdateInformation()
    steps = list(r.GetOutputInformation(0).Get(SDDP.TIME_STEPS()) or [])
    frames = [int(a) for a in sys.argv[3:]] or list(reversed(range(len(steps))))
    result = {"times": steps, "frames": {}}
    for fr in frames:
        r.UpdateTimeStep(steps[fr])
        blocks: dict = {}
        _blocks(r.GetOutputDataObject(0), "root", blocks)
        result["frames"][str(fr)] = blocks
    json.dump(result, sys.stdout)


if __name__ == "__main__":
    main()
