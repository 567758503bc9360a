"""sim.xdmf through both of VTK's XDMF readers, checked against sim.h5.

ParaView opens ``sim.xdmf`` with its XDMF 3 reader by default (vtkXdmf3Reader, "Xdmf3ReaderS/T");
the legacy "XDMF Reader" is vtkXdmfReader (XDMF 2). Each reader runs in its own process
(tests/unit/xdmf_dump.py): pip VTK ships only the XDMF 2 reader, so the XDMF 3 one comes from any
Python whose ``vtkmodules`` has it (Debian: ``apt-get install python3-paraview``; or name one in
SIMCLI_XDMF3_PYTHON); without one that test skips and says so.

Every kind of output entity is covered (particles 2D/3D, FEM tetrahedra with a cell field, PBD
triangles, rods, SF grids 2D/3D), and an entity name that needs XML escaping.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

from simcli.io import EntityMeta, FrameSink

DUMP = Path(__file__).with_name("xdmf_dump.py")
DT = 0.01
NFRAMES = 3
ODD = 'a<b>&"c'  # an entity name that is malformed XML unless escaped
TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
TRIS = np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]])
SEGS = np.array([[0, 1], [1, 2], [2, 3]])
VTK_CELL = {"tets": 10, "triangles": 5, "lines": 4}  # VTK tetra, triangle, poly-line


def entities() -> list[EntityMeta]:
    return [
        EntityMeta(
            "jelly", "particles", 40, 3, {"position": (3, "m"), "velocity": (3, "m/s"), "J": (1, "1")}
        ),
        EntityMeta("sand2d", "particles", 7, 2, {"position": (2, "m"), "velocity": (2, "m/s")}),
        EntityMeta(
            "body",
            "tets",
            5,
            3,
            {"position": (3, "m"), "velocity": (3, "m/s"), "von_mises": (1, "Pa")},
            cells=TETS,
            cell_fields=("von_mises",),
        ),
        EntityMeta("cloth", "triangles", 5, 3, {"position": (3, "m"), "velocity": (3, "m/s")}, cells=TRIS),
        EntityMeta("rope", "lines", 4, 3, {"position": (3, "m"), "tension": (1, "N")}, cells=SEGS),
        EntityMeta(
            "smoke",
            "grid",
            4 * 3 * 2,
            3,
            {"density": (1, "kg/m^3"), "velocity": (3, "m/s")},
            grid_shape=(4, 3, 2),
            origin=(-0.5, -0.25, 0.0),
            spacing=(0.25, 0.25, 0.5),
        ),
        EntityMeta(
            "flow2d",
            "grid",
            12,
            2,
            {"pressure": (1, "Pa", "float64"), "velocity": (2, "m/s")},
            grid_shape=(4, 3),
            origin=(0.0, 0.0),
            spacing=(0.5, 0.5),
        ),
        EntityMeta(ODD, "particles", 3, 3, {"position": (3, "m")}),
    ]


def write_output(out: Path, formats=("hdf5",)) -> list[EntityMeta]:
    ents = entities()
    rng = np.random.default_rng(0)
    sink = FrameSink(out, list(formats))
    sink.open(ents, "version: 1\nname: t\n", {"name": "t", "dt": DT, "dim": 3})
    for fr in range(NFRAMES):
        data = {}
        for e in ents:
            data[e.name] = {f: rng.random(e.frame_shape(f)) + 10 * fr for f in e.fields}
        sink.write_frame(fr, fr * 5, fr * DT, data)
    sink.close()
    return ents


def _vtk_python_with(module: str) -> str | None:
    """A Python interpreter whose vtkmodules has ``module`` (this one first)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    cands = [
        os.environ.get("SIMCLI_XDMF3_PYTHON"),
        sys.executable,
        "/usr/bin/python3",
        shutil.which("python3"),
    ]
    for py in dict.fromkeys(c for c in cands if c):
        try:
            r = subprocess.run(
                [py, "-c", f"import vtkmodules.{module}"], env=env, capture_output=True, timeout=120
            )
        except (OSError, subprocess.TimeoutExpired):
            continue
        if r.returncode == 0:
            return py
    return None


def read_with(reader: str, xdmf: Path) -> dict:
    module = "vtkIOXdmf3" if reader == "vtkXdmf3Reader" else "vtkIOXdmf2"
    py = _vtk_python_with(module)
    if py is None:
        pytest.skip(
            f"no Python with VTK's {reader} here (pip VTK has only the XDMF 2 reader): install Debian's "
            "python3-paraview or set SIMCLI_XDMF3_PYTHON"
        )
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    r = subprocess.run(
        [py, str(DUMP), reader, str(xdmf)], env=env, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, f"{reader} failed (exit {r.returncode}):\n{r.stderr[-3000:]}"
    # what VTK's XDMF 3 reader prints when it drops an array (the 0-point symptom)
    assert "Skipping unrecognized array type" not in r.stderr, r.stderr[-3000:]
    return json.loads(r.stdout)


def _blocks_by_entity(blocks: dict, ents: list[EntityMeta]) -> dict:
    names = [e.name for e in ents]
    if set(blocks) == set(names):
        return blocks
    # the XDMF 3 reader does not name the blocks: they come in the file's (entity) order
    assert len(blocks) == len(ents), list(blocks)
    return dict(zip(names, blocks.values()))


def check_against_h5(result: dict, out: Path, ents: list[EntityMeta], reader: str) -> None:
    with h5py.File(out / "sim.h5", "r") as f:
        np.testing.assert_allclose(result["times"], f["time"][:])
        assert len(result["frames"]) == NFRAMES
        for fr_s, blocks in result["frames"].items():
            fr = int(fr_s)
            got = _blocks_by_entity(blocks, ents)
            for e in ents:
                b = got[e.name]
                g = f["entities"][e.name]
                assert b is not None, f"{reader}: no data for {e.name!r} at frame {fr}"
                if e.kind == "grid":
                    assert b["cells"] == e.n
                    want_dims = [s + 1 for s in e.grid_shape] + ([2] if e.dim == 2 else [])
                    assert b["dimensions"] == want_dims
                    np.testing.assert_allclose(b["origin"][: e.dim], e.origin)
                    np.testing.assert_allclose(b["spacing"][: e.dim], e.spacing)
                    for fname in e.fields:
                        arr = g[fname][fr].reshape(e.n, -1)
                        np.testing.assert_allclose(
                            np.reshape(b["cell_data"][fname], (e.n, -1))[:, : arr.shape[1]], arr, rtol=1e-6
                        )
                    continue
                assert b["points"] == e.n, f"{reader}: {e.name!r} frame {fr}: {b['points']} points"
                pos = g["position"][fr]
                np.testing.assert_allclose(np.asarray(b["xyz"])[:, : e.dim], pos, rtol=1e-6)
                if e.dim == 2:
                    assert not np.any(np.asarray(b["xyz"])[:, 2])
                if e.kind == "particles":  # one (poly)vertex cell per particle, in both readers
                    assert b["cells"] == e.n and set(b["cell_types"]) <= {1, 2}, (reader, b["cells"])
                    assert b["connectivity"] == [[i] for i in range(e.n)]
                else:
                    cells = g["cells"][:]
                    assert b["cells"] == len(cells)
                    assert b["connectivity"] == cells.tolist()
                    if e.kind in VTK_CELL:
                        assert b["cell_types"] == [VTK_CELL[e.kind]]
                for fname in e.fields:
                    if fname == "position":
                        continue
                    where = "cell_data" if fname in e.cell_fields else "point_data"
                    arr = g[fname][fr]
                    vals = np.asarray(b[where][fname])
                    np.testing.assert_allclose(
                        vals.reshape(len(arr), -1)[:, : arr.reshape(len(arr), -1).shape[1]],
                        arr.reshape(len(arr), -1),
                        rtol=1e-6,
                    )


@pytest.mark.parametrize("reader", ["vtkXdmf3Reader", "vtkXdmfReader"])
def test_both_xdmf_readers_read_every_kind(tmp_path, reader):
    ents = write_output(tmp_path)
    result = read_with(reader, tmp_path / "sim.xdmf")
    check_against_h5(result, tmp_path, ents, reader)


def test_xdmf_and_pvd_escape_names(tmp_path):
    """Every name written into sim.xdmf and the .pvd is XML-escaped (both parse; names round-trip)."""
    ents = write_output(tmp_path, formats=("hdf5", "vtk"))
    root = ET.parse(tmp_path / "sim.xdmf").getroot()  # raises on malformed XML
    grids = {g.get("Name") for g in root.iter("Grid") if g.get("GridType") == "Collection"}
    assert grids == {e.name for e in ents}
    frames = [g for g in root.iter("Grid") if (g.get("Name") or "").startswith(ODD + "_")]
    assert len(frames) == NFRAMES
    texts = [d.text for d in frames[0].iter("DataItem") if d.text and "/entities/" in d.text]
    assert texts and all(f"/entities/{ODD}/position" in t or f"/entities/{ODD}/vertices" in t for t in texts)
    assert any(f"/entities/{ODD}/position" in t for t in texts)
    pvd = ET.parse(tmp_path / "vtk" / f"{ODD}.pvd").getroot()
    files = [d.get("file") for d in pvd.iter("DataSet")]
    assert files == [f"{ODD}/{ODD}_{i:06d}.vtu" for i in range(NFRAMES)]
    assert all((tmp_path / "vtk" / f).exists() for f in files)


@pytest.mark.parametrize("reader", ["vtkXdmf3Reader", "vtkXdmfReader"])
def test_a_varying_particle_count_reads_only_the_live_rows(tmp_path, reader):
    """Emitters and sinks: an entity of capacity 10 whose live count changes per frame (sim.h5 pads the rest,
    /entities/<name>/count says how many); both readers see exactly the live particles of each frame."""
    e = EntityMeta("jet", "particles", 10, 2, {"position": (2, "m"), "velocity": (2, "m/s")}, variable=True)
    counts = [0, 7, 4]  # an emitter's first frame holds no particle yet
    rng = np.random.default_rng(1)
    sink = FrameSink(tmp_path, ["hdf5", "vtk"])
    sink.open([e], "version: 1\nname: t\n", {"name": "t", "dt": DT, "dim": 2})
    sent = []
    for fr, c in enumerate(counts):
        d = {f: rng.random((c, 2)) + 10 * fr for f in e.fields}
        sent.append(d)
        sink.write_frame(fr, fr * 5, fr * DT, {"jet": d})
    sink.close()
    with h5py.File(tmp_path / "sim.h5", "r") as f:
        assert list(f["entities/jet/count"][:]) == counts
        assert f["entities/jet/position"].shape == (3, 10, 2)
        assert np.isnan(f["entities/jet/position"][1, 7:]).all()
    result = read_with(reader, tmp_path / "sim.xdmf")
    assert len(result["frames"]) == len(counts)
    for fr_s, blocks in result["frames"].items():
        fr = int(fr_s)
        b = list(blocks.values())[0]
        assert b["points"] == counts[fr] and b["cells"] == counts[fr], (reader, fr, b["points"])
        if counts[fr] == 0:
            continue
        np.testing.assert_allclose(np.asarray(b["xyz"])[:, :2], sent[fr]["position"], rtol=1e-6)
        np.testing.assert_allclose(
            np.asarray(b["point_data"]["velocity"])[:, :2], sent[fr]["velocity"], rtol=1e-6
        )
    vtu = (tmp_path / "vtk" / "jet" / "jet_000001.vtu").read_bytes()
    assert b'NumberOfPoints="7" NumberOfCells="7"' in vtu
