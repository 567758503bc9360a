"""FEM obstacle lookup (simcli.solvers.fem.contact.make_nearest) returns the nearest obstacle's
friction and contact kind (issue 19: `mu = ti.static(...)` inside the loop only rebound a Python
name, so every wall and collider had friction 0 and none was sticky)."""

import numpy as np


def test_nearest_returns_the_obstacles_friction_and_kind(ti_f32):
    import taichi as ti

    from simcli.scene.models import Scene
    from simcli.solvers.fem.contact import KIND_ID, make_nearest

    scene = Scene.model_validate(
        {
            "domain": {
                "lower": [0, 0, 0],
                "upper": [1, 1, 1],
                "faces": {"z-": {"type": "slip", "friction": 0.5}},
            },
            "colliders": [
                {
                    "type": "Sphere",
                    "center": [0.5, 0.5, 0.6],
                    "radius": 0.1,
                    "boundary": "sticky",
                    "friction": 0.3,
                }
            ],
            "entities": [
                {
                    "name": "a",
                    "material": {"type": "FEM.Elastic", "E": 1e5, "nu": 0.3, "rho": 1000},
                    "morph": {"type": "Box", "lower": [0.1, 0.1, 0.0], "upper": [0.2, 0.2, 0.1]},
                }
            ],
        }
    )
    nearest = make_nearest(scene, 3)
    pts = np.array([[0.3, 0.4, -1e-4], [0.5, 0.5, 0.55], [0.9, 0.5, 0.5]], np.float32)
    xs = ti.Vector.field(3, ti.f32, shape=3)
    out = ti.Vector.field(3, ti.f32, shape=3)  # phi, mu, kind
    xs.from_numpy(pts)

    @ti.kernel
    def k():
        for i in range(3):
            phi, _n, kind, mu, _v, _idx = nearest(xs[i])
            out[i] = ti.Vector([phi, mu, ti.cast(kind, ti.f32)])

    k()
    r = out.to_numpy()
    assert r[0, 0] < 0 and r[0, 1] == np.float32(0.5) and r[0, 2] == KIND_ID["slip"]  # the floor face
    assert r[1, 0] < 0 and r[1, 1] == np.float32(0.3) and r[1, 2] == KIND_ID["sticky"]  # inside the sphere
    assert r[2, 1] == 0.0  # nearest is the frictionless x+ face
