"""Frame writers: sim.h5 (SWMR, crash-safe), sim.xdmf (through VTK's reader), VTK files + pvd."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import textwrap
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest

import simcli
from simcli.errors import EXIT_OUTPUT, OutputError
from simcli.io import EntityMeta, FrameSink, clear_status_flags, open_frames
from simcli.io.hdf5 import lookup3

REPO = Path(__file__).resolve().parents[2]
DT = 0.01


# -- a deterministic scene of every entity kind ---------------------------------------------

TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
TRIS = np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]])
SEGS = np.array([[0, 1], [1, 2], [2, 3]])


def entities(n: int = 50) -> list[EntityMeta]:
    return [
        EntityMeta("jelly", "particles", n, 3, {"position": (3, "m"), "velocity": (3, "m/s"), "J": (1, "1")}),
        EntityMeta("body", "tets", 5, 3, {"position": (3, "m"), "velocity": (3, "m/s")}, cells=TETS),
        EntityMeta("cloth", "triangles", 5, 3, {"position": (3, "m")}, cells=TRIS),
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
        EntityMeta("sand2d", "particles", 7, 2, {"position": (2, "m"), "velocity": (2, "m/s")}),
        EntityMeta(
            "flow2d",
            "grid",
            12,
            2,
            {"pressure": (1, "Pa"), "velocity": (2, "m/s")},
            grid_shape=(4, 3),
            origin=(0.0, 0.0),
            spacing=(0.5, 0.5),
        ),
    ]


def frame_data(ents: list[EntityMeta], fr: int) -> dict:
    """Frame ``fr``: every value encodes (frame, entity, field, index) so mix-ups show."""
    out = {}
    for k, e in enumerate(ents):
        d = {}
        for j, (fname, (comps, _u, _dt)) in enumerate(e.fields.items()):
            shape = e.frame_shape(fname)
            size = int(np.prod(shape))
            values = fr * 1000 + k * 100 + j * 10 + np.arange(size) / size
            d[fname] = values.reshape(shape).astype(np.float32)
        out[e.name] = d
    return out


def write_run(out: Path, frames, formats=("hdf5", "vtk"), ents=None, resume_frame=None) -> FrameSink:
    ents = ents or entities()
    sink = FrameSink(out, list(formats))
    sink.open(
        ents,
        "version: 1\nname: t\n",
        {"name": "t", "dt": DT, "dim": 3, "extra": {"a": [1, 2]}},
        resume_frame=resume_frame,
    )
    for fr in frames:
        sink.write_frame(fr, fr * 5, fr * DT, frame_data(ents, fr))
    sink.close()
    return sink


def xdmf_frames(path: Path, entity: str = "jelly") -> int:
    root = ET.parse(path).getroot()
    return len([g for g in root.iter("Grid") if g.get("Name", "").startswith(entity + "_")])


def pvd_files(pvd: Path) -> list[tuple[float, str]]:
    root = ET.parse(pvd).getroot()
    assert root.get("type") == "Collection"
    return [(float(d.get("timestep")), d.get("file")) for d in root.iter("DataSet")]


# -- sim.h5 ------------------------------------------------------------------------------------


def test_h5_layout_and_roundtrip(tmp_path):
    ents = entities()
    write_run(tmp_path, range(3), formats=["hdf5"], ents=ents)
    with h5py.File(tmp_path / "sim.h5", "r") as f:  # cleanly closed: any reader opens it
        assert f.attrs["format"] == "simcli-frames"
        assert f.attrs["format_version"] == 1
        assert f.attrs["simcli_version"] == simcli.__version__
        assert f.attrs["scene"].startswith("version: 1")
        assert f.attrs["name"] == "t" and f.attrs["dt"] == DT and '"a"' in f.attrs["extra"]
        np.testing.assert_allclose(f["time"][:], [0, DT, 2 * DT])
        np.testing.assert_array_equal(f["step"][:], [0, 5, 10])
        assert f["time"].maxshape == (None,) and f["time"].attrs["unit"] == "s"
        for e in ents:
            g = f["entities"][e.name]
            assert g.attrs["kind"] == e.kind
            for fname, (comps, unit, _dt) in e.fields.items():
                d = g[fname]
                assert d.attrs["unit"] == unit
                assert d.maxshape[0] is None and d.chunks == (1,) + d.shape[1:]
                assert d.shape == (3,) + e.frame_shape(fname)
                for fr in range(3):
                    np.testing.assert_array_equal(d[fr], frame_data(ents, fr)[e.name][fname])
            if e.cells is not None:
                np.testing.assert_array_equal(g["cells"][:], e.cells)
                assert g["cells"].attrs["unit"] == "1"
        assert f["entities/jelly/position"].shape == (3, 50, 3)
        assert f["entities/jelly/J"].shape == (3, 50)
        sm = f["entities/smoke/velocity"]
        assert sm.shape == (3, 2, 3, 4, 3)  # (frames, nz, ny, nx, comps)
        np.testing.assert_allclose(sm.attrs["origin"], [-0.5, -0.25, 0.0])
        np.testing.assert_allclose(sm.attrs["spacing"], [0.25, 0.25, 0.5])
        assert f["entities/flow2d/pressure"].shape == (3, 3, 4)  # (frames, ny, nx)
    with open_frames(tmp_path / "sim.h5") as f:  # the SWMR reader also opens a closed file
        assert f["time"].shape == (3,)


def test_input_shapes_are_checked_and_flat_grids_accepted(tmp_path):
    e = EntityMeta("g", "grid", 24, 3, {"d": (1, "1")}, grid_shape=(4, 3, 2))
    sink = FrameSink(tmp_path, ["hdf5"])
    sink.open([e], "", {})
    flat = np.arange(24.0)
    sink.write_frame(0, 0, 0.0, {"g": {"d": flat}})  # flattened, x fastest
    with pytest.raises(ValueError, match="x varies fastest"):
        sink.write_frame(1, 1, 0.1, {"g": {"d": flat.reshape(4, 3, 2)}})  # x, y, z order: refused
    with pytest.raises(ValueError, match="expected frame 1"):
        sink.write_frame(2, 1, 0.1, {"g": {"d": flat}})
    with pytest.raises(ValueError, match="missing fields"):
        sink.write_frame(1, 1, 0.1, {"g": {}})
    sink.close()
    with h5py.File(tmp_path / "sim.h5") as f:
        np.testing.assert_array_equal(f["entities/g/d"][0], flat.reshape(2, 3, 4))
    with pytest.raises(ValueError, match="needs cells"):
        EntityMeta("m", "tets", 4, 3, {"position": (3, "m")})
    with pytest.raises(ValueError, match="index outside"):
        EntityMeta("m", "triangles", 3, 3, {"position": (3, "m")}, cells=[[0, 1, 3]])


def test_lookup3_matches_hdf5_superblock_checksum(tmp_path):
    with h5py.File(tmp_path / "a.h5", "w", libver=("v110", "v110")) as f:
        f["x"] = 1
    sb = (tmp_path / "a.h5").read_bytes()[:48]
    assert sb[8] >= 2
    assert lookup3(sb[:44]) == int.from_bytes(sb[44:48], "little")
    assert lookup3(b"") == 0xDEADBEEF  # reference values of hashlittle
    assert lookup3(b"Four score and seven years ago") == 0x17770551


# -- SIGKILL mid-run ---------------------------------------------------------------------------

WRITER = textwrap.dedent(
    """
    import os, signal, sys
    from pathlib import Path
    sys.path.insert(0, {repo!r})
    import h5py
    from tests.unit.test_io import entities, frame_data, DT
    from simcli.io import FrameSink
    mode = sys.argv[1]
    ents = entities(n=200_000)   # tens of ms per frame, so a timed kill lands mid-write
    sink = FrameSink(Path({out!r}), ["hdf5", "vtk"])
    sink.open(ents, "version: 1", {{}})

    def die(*a, **k):
        os.kill(os.getpid(), signal.SIGKILL)

    for fr in range(100_000):
        if fr == 6 and mode == "h5_half_frame":   # frame data flushed, /time extended but not flushed
            real_flush, calls = h5py.File.flush, []
            def flush(self):
                calls.append(1)
                die() if len(calls) == 2 else real_flush(self)
            h5py.File.flush = flush
        if fr == 6 and mode in ("vtu_tmp", "pvd_stale"):
            real_replace = os.replace
            suffix = ".vtu" if mode == "vtu_tmp" else ".pvd"
            os.replace = lambda a, b: die() if str(b).endswith(suffix) else real_replace(a, b)
        sink.write_frame(fr, fr * 5, fr * DT, frame_data(ents, fr))
        print("frame", fr, "done", flush=True)
    """
)


@pytest.mark.parametrize("mode", ["timed", "h5_half_frame", "vtu_tmp", "pvd_stale"])
def test_sigkill_leaves_every_completed_frame_readable(tmp_path, mode):
    """SIGKILL a writer mid-run: at a random point of frame 6 ("timed", from outside) or at
    the worst moments (between the frame data and /time; before a .vtu / .pvd rename)."""
    out = tmp_path / "out"
    script = tmp_path / "writer.py"
    script.write_text(WRITER.format(repo=str(REPO), out=str(out)))
    proc = subprocess.Popen([sys.executable, str(script), mode], stdout=subprocess.PIPE, text=True)
    try:
        done = -1
        for line in proc.stdout:
            done = int(line.split()[1])
            if done >= 5 and mode == "timed":
                time.sleep(0.02)  # inside the next frame
                proc.send_signal(signal.SIGKILL)
                break
        proc.wait(timeout=60)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert done >= 5

    ents = entities(n=200_000)
    # 1. an SWMR reader opens the file as the killed writer left it
    with h5py.File(out / "sim.h5", "r", swmr=True) as f:
        nt = f["time"].shape[0]
        assert nt >= done + 1
        if mode == "h5_half_frame":
            assert nt == 6 and f["entities/jelly/position"].shape[0] == 7  # the half frame is not listed
        assert f["step"].shape[0] >= nt
        np.testing.assert_allclose(f["time"][:], np.arange(nt) * DT)
        for fr in range(nt):  # every frame /time lists is complete
            want = frame_data(ents, fr)
            for e in ents:
                for fname in e.fields:
                    np.testing.assert_array_equal(f[f"entities/{e.name}/{fname}"][fr], want[e.name][fname])
    # 2. the xdmf lists the frames of sim.h5 (it is rewritten right after each frame)
    n_xdmf = xdmf_frames(out / "sim.xdmf")
    assert n_xdmf in (nt - 1, nt)
    # 3. each pvd lists only files that exist (at most the file of the frame being written is unlisted)
    for e in ents:
        listed = {f for _t, f in pvd_files(out / "vtk" / f"{e.name}.pvd")}
        assert listed and all((out / "vtk" / f).is_file() for f in listed)
        present = {f"{e.name}/{p.name}" for p in (out / "vtk" / e.name).glob(f"{e.name}_*.vt?")}
        assert listed <= present and len(present - listed) <= 1
    if mode == "vtu_tmp":
        assert list((out / "vtk" / "jelly").glob(".jelly_000006.vtu.*.tmp"))
        assert not (out / "vtk" / "jelly" / "jelly_000006.vtu").exists()
    if mode == "pvd_stale":
        assert (out / "vtk" / "jelly" / "jelly_000006.vtu").exists()
        assert len(pvd_files(out / "vtk" / "jelly.pvd")) == 6
    # 4. clearing HDF5's "open for write" flags lets every HDF5 tool open it
    assert clear_status_flags(out / "sim.h5")
    with h5py.File(out / "sim.h5", "r") as f:
        assert f["time"].shape[0] == nt
    # 5. resume from frame 4 after the crash
    sink = FrameSink(out, ["hdf5", "vtk"])
    sink.open(ents, "version: 1", {}, resume_frame=4)
    sink.write_frame(4, 20, 4 * DT, frame_data(ents, 4))
    sink.close()
    with h5py.File(out / "sim.h5", "r") as f:
        assert f["time"].shape == (5,) and f["entities/jelly/position"].shape[0] == 5
        np.testing.assert_array_equal(f["entities/jelly/J"][4], frame_data(ents, 4)["jelly"]["J"])
    assert len(pvd_files(out / "vtk" / "jelly.pvd")) == 5
    names = sorted(p.name for p in (out / "vtk" / "jelly").iterdir())
    assert names == [f"jelly_{i:06d}.vtu" for i in range(5)]


def test_resume_after_kill_without_explicit_flag_clearing(tmp_path):
    """open(resume_frame=k) clears the killed writer's flags itself."""
    ents = entities()
    sink = FrameSink(tmp_path, ["hdf5"])
    sink.open(ents, "", {})
    for fr in range(3):
        sink.write_frame(fr, fr, fr * DT, frame_data(ents, fr))
    # simulate the kill: copy the file while it is open for SWMR writing
    import shutil

    shutil.copy(tmp_path / "sim.h5", tmp_path / "copy.h5")
    sink.close()
    killed = tmp_path / "k"
    killed.mkdir()
    shutil.move(tmp_path / "copy.h5", killed / "sim.h5")
    with pytest.raises(OSError):
        h5py.File(killed / "sim.h5", "r")  # flags still set
    sink = FrameSink(killed, ["hdf5"])
    sink.open(ents, "", {}, resume_frame=2)
    sink.write_frame(2, 2, 2 * DT, frame_data(ents, 2))
    sink.close()
    with h5py.File(killed / "sim.h5", "r") as f:
        assert f["time"].shape == (3,)


# -- resume ------------------------------------------------------------------------------------


def test_resume_truncates_and_appends(tmp_path):
    ents = entities()
    write_run(tmp_path, range(10), ents=ents)
    assert len(pvd_files(tmp_path / "vtk" / "jelly.pvd")) == 10
    # frames 6.. are redone with different data (resume_frame=6)
    sink = FrameSink(tmp_path, ["hdf5", "vtk"])
    sink.open(ents, "version: 1\n", {"name": "t"}, resume_frame=6)
    for fr in (6, 7, 8):
        sink.write_frame(fr, fr * 5, fr * DT, frame_data(ents, fr + 50))
    sink.close()
    with h5py.File(tmp_path / "sim.h5", "r") as f:
        assert f["time"].shape == (9,) and f["step"].shape == (9,)
        np.testing.assert_allclose(f["time"][:], np.arange(9) * DT)
        for e in ents:
            for fname in e.fields:
                d = f[f"entities/{e.name}/{fname}"]
                assert d.shape[0] == 9
                for fr in range(9):
                    src = fr if fr < 6 else fr + 50
                    np.testing.assert_array_equal(d[fr], frame_data(ents, src)[e.name][fname])
    for e in ents:
        entries = pvd_files(tmp_path / "vtk" / f"{e.name}.pvd")
        assert [t for t, _ in entries] == pytest.approx(list(np.arange(9) * DT))
        listed = [f for _t, f in entries]
        assert len(listed) == 9 and all((tmp_path / "vtk" / f).is_file() for f in listed)
        present = sorted(f"{e.name}/{p.name}" for p in (tmp_path / "vtk" / e.name).iterdir())
        assert present == sorted(listed)  # frame 9 deleted, nothing else lying around
    m = meshio.read(tmp_path / "vtk" / "jelly" / "jelly_000007.vtu")
    np.testing.assert_array_equal(m.point_data["J"], frame_data(ents, 57)["jelly"]["J"])
    assert xdmf_frames(tmp_path / "sim.xdmf") == 9


def test_resume_errors(tmp_path):
    ents = entities()
    with pytest.raises(OutputError, match="does not exist"):
        FrameSink(tmp_path / "none", ["hdf5"]).open(ents, "", {}, resume_frame=2)
    write_run(tmp_path, range(3), formats=["hdf5"], ents=ents)
    with pytest.raises(OutputError, match="holds only 3"):
        FrameSink(tmp_path, ["hdf5"]).open(ents, "", {}, resume_frame=5)
    other = [EntityMeta("other", "particles", 3, 3, {"position": (3, "m")})]
    with pytest.raises(OutputError, match="scene changed"):
        FrameSink(tmp_path, ["hdf5"]).open(other, "", {}, resume_frame=1)


# -- VTK files ---------------------------------------------------------------------------------


def test_vtk_files_roundtrip(tmp_path):
    ents = entities()
    write_run(tmp_path, range(3), formats=["vtk"], ents=ents)
    assert not (tmp_path / "sim.h5").exists()
    want = frame_data(ents, 2)
    cell_type = {"jelly": "vertex", "body": "tetra", "cloth": "triangle", "rope": "line", "sand2d": "vertex"}
    for name, ctype in cell_type.items():
        entries = pvd_files(tmp_path / "vtk" / f"{name}.pvd")
        assert entries == [
            (0.0, f"{name}/{name}_000000.vtu"),
            (DT, f"{name}/{name}_000001.vtu"),
            (2 * DT, f"{name}/{name}_000002.vtu"),
        ]
        text = (tmp_path / "vtk" / entries[-1][1]).read_bytes()
        assert b'compressor="vtkZLibDataCompressor"' in text and b'encoding="raw"' in text
        m = meshio.read(tmp_path / "vtk" / entries[-1][1])
        pos = want[name]["position"]
        np.testing.assert_array_equal(m.points[:, : pos.shape[1]], pos)
        assert [c.type for c in m.cells] == [ctype]
        for fname, arr in want[name].items():
            if fname == "position":
                continue
            got = m.point_data[fname]
            np.testing.assert_array_equal(got[..., : arr.shape[1]] if arr.ndim == 2 else got, arr)
    np.testing.assert_array_equal(meshio.read(tmp_path / "vtk/body/body_000002.vtu").cells[0].data, TETS)
    # 2D vectors are padded to 3 components for ParaView
    m = meshio.read(tmp_path / "vtk/sand2d/sand2d_000002.vtu")
    assert m.points.shape == (7, 3) and m.point_data["velocity"].shape == (7, 3)
    assert not m.point_data["velocity"][:, 2].any()
    assert (tmp_path / "vtk/smoke/smoke_000002.vti").is_file()


def test_vtk_files_open_in_vtk(tmp_path):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    ents = entities(n=300_000)  # > one compression block per array
    write_run(tmp_path, range(2), formats=["vtk"], ents=ents)
    want = frame_data(ents, 1)
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(tmp_path / "vtk/jelly/jelly_000001.vtu"))
    r.Update()
    ug = r.GetOutput()
    assert ug.GetNumberOfPoints() == 300_000 and ug.GetNumberOfCells() == 300_000
    np.testing.assert_array_equal(vtk_to_numpy(ug.GetPoints().GetData()), want["jelly"]["position"])
    np.testing.assert_array_equal(vtk_to_numpy(ug.GetPointData().GetArray("J")), want["jelly"]["J"])
    r = vtk.vtkXMLImageDataReader()
    r.SetFileName(str(tmp_path / "vtk/smoke/smoke_000001.vti"))
    r.Update()
    img = r.GetOutput()
    assert img.GetDimensions() == (5, 4, 3) and img.GetNumberOfCells() == 24
    assert img.GetOrigin() == pytest.approx((-0.5, -0.25, 0.0))
    assert img.GetSpacing() == pytest.approx((0.25, 0.25, 0.5))
    np.testing.assert_array_equal(
        vtk_to_numpy(img.GetCellData().GetArray("density")), want["smoke"]["density"].reshape(-1)
    )
    np.testing.assert_array_equal(
        vtk_to_numpy(img.GetCellData().GetArray("velocity")), want["smoke"]["velocity"].reshape(-1, 3)
    )
    r = vtk.vtkXMLImageDataReader()
    r.SetFileName(str(tmp_path / "vtk/flow2d/flow2d_000001.vti"))
    r.Update()
    assert r.GetOutput().GetDimensions() == (5, 4, 1)
    r = vtk.vtkPVDReader() if hasattr(vtk, "vtkPVDReader") else None
    if r is not None:
        r.SetFileName(str(tmp_path / "vtk/jelly.pvd"))
        r.UpdateInformation()
        assert r.GetNumberOfTimeSteps() == 2


# -- sim.xdmf through VTK's reader -------------------------------------------------------------


def _xdmf_reader(vtk):
    for cls in ("vtkXdmf3Reader", "vtkXdmfReader"):
        if hasattr(vtk, cls):
            return getattr(vtk, cls)()
    pytest.skip("this vtk has no XDMF reader")


def test_xdmf_opens_in_vtk(tmp_path):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    ents = entities()
    write_run(tmp_path, range(3), ents=ents)
    r = _xdmf_reader(vtk)
    r.SetFileName(str(tmp_path / "sim.xdmf"))
    r.UpdateInformation()
    steps = r.GetOutputInformation(0).Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS())
    assert list(steps) == pytest.approx([0.0, DT, 2 * DT])
    for fr in (2, 0, 1):  # last first; then back: nothing may be served from a stale cache
        r.UpdateTimeStep(steps[fr])
        mb = r.GetOutputDataObject(0)
        blocks = {
            mb.GetMetaData(i).Get(vtk.vtkCompositeDataSet.NAME()): mb.GetBlock(i)
            for i in range(mb.GetNumberOfBlocks())
        }
        assert set(blocks) == {e.name for e in ents}
        want = frame_data(ents, fr)
        for e in ents:
            b = blocks[e.name]
            if e.kind == "grid":
                assert b.GetNumberOfCells() == e.n
                assert b.GetDimensions()[: e.dim] == tuple(s + 1 for s in e.grid_shape)
                assert b.GetOrigin()[: e.dim] == pytest.approx(e.origin)
                assert b.GetSpacing()[: e.dim] == pytest.approx(e.spacing)
                for fname, arr in want[e.name].items():
                    got = vtk_to_numpy(b.GetCellData().GetArray(fname))
                    np.testing.assert_array_equal(
                        got[..., : e.dim] if arr.ndim > e.dim else got,
                        arr.reshape(got.shape[0], -1).squeeze(),
                    )
                continue
            assert b.GetNumberOfPoints() == e.n
            ncells = e.n if e.kind == "particles" else len(e.cells)
            assert b.GetNumberOfCells() == ncells
            pts = vtk_to_numpy(b.GetPoints().GetData())
            np.testing.assert_array_equal(pts[:, : e.dim], want[e.name]["position"])
            for fname, arr in want[e.name].items():
                if fname != "position":
                    got = vtk_to_numpy(b.GetPointData().GetArray(fname))
                    np.testing.assert_array_equal(got[:, : arr.shape[1]] if arr.ndim == 2 else got, arr)
        cell = blocks["body"].GetCell(1)
        assert cell.GetCellType() == vtk.VTK_TETRA
        assert [cell.GetPointId(i) for i in range(4)] == list(TETS[1])


# -- errors ------------------------------------------------------------------------------------


def test_unwritable_folder_raises_output_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    for fmts in (["hdf5"], ["vtk"]):
        with pytest.raises(OutputError, match=str(blocker)) as ei:
            FrameSink(blocker / "out", fmts).open(entities(), "", {})
        assert ei.value.exit_code == EXIT_OUTPUT == 74


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_raises_output_error(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="permission denied"):
            FrameSink(ro, ["hdf5", "vtk"]).open(entities(), "", {})
    finally:
        ro.chmod(0o700)


def test_disk_full_raises_output_error(tmp_path, monkeypatch):
    sink = FrameSink(tmp_path, ["hdf5", "vtk"])
    ents = entities()
    sink.open(ents, "", {})
    sink.write_frame(0, 0, 0.0, frame_data(ents, 0))

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(h5py.Dataset, "write_direct", full)
    with pytest.raises(OutputError, match=r"sim\.h5: disk full"):
        sink.write_frame(1, 1, DT, frame_data(ents, 1))
    monkeypatch.undo()
    sink.close()

    sink = FrameSink(tmp_path / "v", ["vtk"])
    sink.open(ents, "", {})
    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OutputError, match=r"jelly_000000\.vtu: disk full"):
        sink.write_frame(0, 0, 0.0, frame_data(ents, 0))
    monkeypatch.undo()
    assert not [p for p in (tmp_path / "v/vtk/jelly").iterdir()]  # the temp file was removed
    sink.close()


def test_io_does_not_import_taichi():
    code = "import sys, simcli.io.hdf5, simcli.io.xdmf, simcli.io.vtk\nassert 'taichi' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)
