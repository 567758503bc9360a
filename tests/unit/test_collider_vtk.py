"""Collider surface meshes per frame (simcli.io.collider_vtk): closed, outward, moved by the motion."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from simcli.io.collider_vtk import ColliderVtkWriter, collider_surface
from simcli.motion import make_motion
from simcli.scene.models import Motion as MotionModel


def _spec(kind, a=(0, 0, 0), b=(0, 0, 0), radius=0.0, half_height=0.0, axis=2):
    return SimpleNamespace(kind=kind, a=a, b=b, radius=radius, half_height=half_height, axis=axis)


def _volume(pts, tris):
    """Signed volume by the divergence theorem: positive for a closed, outward-oriented surface."""
    p = pts[tris]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


def _closed(tris):
    edges = {}
    for t in tris:
        for i in range(3):
            e = (int(t[i]), int(t[(i + 1) % 3]))
            edges[e] = edges.get(e, 0) + 1
    return all(edges.get((b, a), 0) == 1 for (a, b) in edges) and all(v == 1 for v in edges.values())


@pytest.mark.parametrize(
    "spec, volume, rel",
    [
        (_spec("Box", (0, 0, 0), (0.1, 0.2, 0.3)), 0.006, 1e-12),
        (_spec("Sphere", (0.1, 0, 0), radius=0.2), 4 / 3 * math.pi * 0.2**3, 0.02),
        (_spec("Cylinder", (0, 0.1, 0), radius=0.1, half_height=0.2, axis=0), math.pi * 0.01 * 0.4, 0.02),
    ],
)
def test_3d_surfaces_are_closed_outward_and_enclose_the_collider(spec, volume, rel):
    pts, tris = collider_surface(spec, 3, 1.0)
    assert _closed(tris)
    assert _volume(pts, tris) == pytest.approx(volume, rel=rel)


def test_written_frames_follow_the_motion_and_read_back_with_vtk(tmp_path):
    vtk = pytest.importorskip("vtk")
    spec = _spec("Box", (0.2, 0.06), (0.38, 0.075))
    motion = make_motion(MotionModel(angular_velocity=[math.pi]), 2, np.array([0.29, 0.0675]))
    w = ColliderVtkWriter(tmp_path, [("paddle", spec, motion)], 2, 1.0)
    w.open(None)
    w.write_frame(0, 0.0)
    w.write_frame(1, 1.0)  # half a turn: each corner goes to its mirror image through the centre
    r = vtk.vtkXMLPolyDataReader()
    r.SetFileName(str(tmp_path / "paddle" / "paddle_000001.vtp"))
    r.Update()
    out = r.GetOutput()
    assert out.GetNumberOfLines() == 4
    x = np.array([out.GetPoint(i) for i in range(out.GetNumberOfPoints())])[:, :2]
    assert np.allclose(x[0], 2 * np.array([0.29, 0.0675]) - np.array([0.2, 0.06]))
    assert (tmp_path / "paddle.pvd").read_text().count("<DataSet") == 2
