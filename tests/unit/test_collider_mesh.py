"""Mesh colliders on the host: their VTK surface is the mesh itself, moved to the frame's pose."""

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def test_mesh_collider_vtk_surface_is_its_own_triangles(tmp_path):
    from simcli.colliders import collider_vtk_items
    from simcli.io.collider_vtk import ColliderVtkWriter
    from simcli.scene.models import Scene

    scene = Scene.model_validate(
        {
            "domain": {"lower": [0, 0, 0], "upper": [1, 1, 1]},
            "colliders": [
                {
                    "name": "paddle",
                    "type": "Mesh",
                    "file": "star_paddle.obj",
                    "scale": 0.1,
                    "translate": [0.5, 0.5, 0.5],
                    "motion": {"angular_velocity": [0, 0, 3.14159265]},
                }
            ],
        }
    )
    items = collider_vtk_items(scene, ROOT / "configs" / "meshes")
    (name, spec, motion) = items[0]
    assert name == "paddle" and spec.kind == "Mesh"
    w = ColliderVtkWriter(tmp_path, items, 3, 1.0)
    w.open(None)
    w.write_frame(3, 1.0)  # half a turn about z through the pivot (0.5, 0.5, 0.5)
    text = (tmp_path / "paddle" / "paddle_000003.vtp").read_text()
    assert f'NumberOfPoints="{len(spec.mesh.vertices)}"' in text
    assert f'NumberOfPolys="{len(spec.mesh.triangles)}"' in text
    pts = text.split("<Points>")[1].split(">", 2)[1].split("<")[0]
    x = np.array(pts.split(), float).reshape(-1, 3)
    expect = spec.mesh.vertices.copy()
    expect[:, :2] = 1.0 - expect[:, :2]  # rotated by pi about the vertical axis through (0.5, 0.5)
    assert np.allclose(x, expect, atol=1e-6)
