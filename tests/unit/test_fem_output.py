"""Per-cell output fields of mesh entities (FEM's von Mises stress and J): cell data in each .vtu, datasets
(frames, n_cells) with center = "cell" in sim.h5, Center="Cell" attributes in sim.xdmf; point fields of
the same entity unchanged, and a cell field of the wrong length rejected."""

import h5py
import meshio
import numpy as np
import pytest

from simcli.io.frames import EntityMeta, FrameSink

X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=np.float64)
CELLS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def _meta():
    return EntityMeta(
        name="body",
        kind="tets",
        n=5,
        dim=3,
        cells=CELLS,
        fields={"position": (3, "m"), "velocity": (3, "m/s"), "von_mises": (1, "Pa"), "J": (1, "1")},
        cell_fields=("von_mises", "J"),
    )


def test_cell_fields_in_vtu_h5_and_xdmf(tmp_path):
    sink = FrameSink(tmp_path, ["hdf5", "vtk"])
    sink.open([_meta()], "scene: text")
    for k in range(2):
        sink.write_frame(
            k,
            k,
            0.1 * k,
            {
                "body": {
                    "position": X + k,
                    "velocity": np.full((5, 3), float(k)),
                    "von_mises": np.array([1.0, 2.0]) * (k + 1),
                    "J": np.array([1.0, 0.5]),
                }
            },
        )
    sink.close()
    m = meshio.read(tmp_path / "vtk" / "body" / "body_000001.vtu")
    assert np.allclose(m.points, X + 1)
    assert np.allclose(m.cell_data["von_mises"][0], [2.0, 4.0]) and np.allclose(
        m.cell_data["J"][0], [1.0, 0.5]
    )
    assert np.allclose(m.point_data["velocity"], 1.0) and "von_mises" not in m.point_data
    with h5py.File(tmp_path / "sim.h5") as f:
        g = f["entities/body"]
        assert g["von_mises"].shape == (2, 2) and g["von_mises"].attrs["center"] == "cell"
        assert g["velocity"].shape == (2, 5, 3) and "center" not in g["velocity"].attrs
        assert np.allclose(g["von_mises"][1], [2.0, 4.0])
    xdmf = (tmp_path / "sim.xdmf").read_text()
    assert 'Name="von_mises" AttributeType="Scalar" Center="Cell"' in xdmf
    assert 'Name="velocity" AttributeType="Vector" Center="Node"' in xdmf


def test_cell_field_of_wrong_length_rejected(tmp_path):
    sink = FrameSink(tmp_path, ["hdf5"])
    sink.open([_meta()], "scene: text")
    with pytest.raises(ValueError, match="von_mises"):
        sink.write_frame(
            0, 0, 0.0, {"body": {"position": X, "velocity": X, "von_mises": np.zeros(5), "J": np.zeros(2)}}
        )
    sink.close()


def test_cell_field_must_be_declared_on_a_mesh():
    with pytest.raises(ValueError, match="cell field"):
        EntityMeta(
            name="p",
            kind="particles",
            n=5,
            dim=3,
            fields={"position": (3, "m"), "J": (1, "1")},
            cell_fields=("J",),
        )
