"""simcli.colliders.ColliderPoses: the per-substep pose upload (host buffer -> Taichi field)."""

import math

import numpy as np
import pytest
import yaml


def _scene(dim):
    from simcli.scene.models import Scene

    if dim == 2:
        cols = [
            {"type": "Box", "name": "still", "lower": [0.1, 0.1], "upper": [0.2, 0.2]},
            {"type": "Box", "lower": [0.3, 0.1], "upper": [0.4, 0.2], "motion": {"angular_velocity": [3.0]}},
            {
                "type": "Box",
                "lower": [0.5, 0.1],
                "upper": [0.6, 0.2],
                "motion": {
                    "keyframes": {"times": [0, 1], "translate": [[0, 0], [0.2, 0.1]], "rotate": [[0], [30]]}
                },
            },
        ]
        dom = {"lower": [0, 0], "upper": [1, 1]}
    else:
        cols = [
            {"type": "Box", "name": "still", "lower": [0.1, 0.1, 0.1], "upper": [0.2, 0.2, 0.2]},
            {
                "type": "Box",
                "lower": [0.3, 0.1, 0.1],
                "upper": [0.4, 0.2, 0.2],
                "motion": {"linear_velocity": [0.1, 0, 0], "angular_velocity": [1.0, -2.0, 4 * math.pi]},
            },
        ]
        dom = {"lower": [0, 0, 0], "upper": [1, 1, 1]}
    return Scene.model_validate(
        yaml.safe_load(
            yaml.safe_dump({"sim": {"dim": dim}, "domain": dom, "colliders": cols, "entities": []})
        )
    )


@pytest.mark.parametrize("dim", [2, 3])
def test_set_time_uploads_every_colliders_pose_at_both_slot_times(ti_f32, dim):
    """Slot 0 holds each collider's pose at the middle of the substep, slot 1 at its end, as pose() gives
    them (float32); a still named collider's row, written once, stays its identity pose."""
    import taichi as ti

    from simcli.colliders import ColliderPoses, collider_motions, collider_specs

    scene = _scene(dim)
    specs, motions = collider_specs(scene, dim), collider_motions(scene, dim)
    poses = ColliderPoses(specs, motions, dim, ti.f32)
    poses.allocate()
    for t, dt in ((0.0, 0.01), (0.37, 0.002), (0.81, 0.004)):
        poses.set_time(t, dt)
        got = poses.pose.to_numpy()
        for k, (c, m) in enumerate(zip(specs, motions)):
            for slot, ts in enumerate((t + 0.5 * dt, t + dt)):
                row = got[slot, k]
                if m is None:
                    R, cen, v, w = np.eye(dim), np.asarray(c.centre), np.zeros(dim), np.zeros(3)
                else:
                    p = m.pose(ts)
                    R, cen, v, w = p.R, p.c, p.v, p.w
                np.testing.assert_array_equal(row[: dim * dim], np.float32(R).reshape(-1))
                np.testing.assert_array_equal(row[9 : 9 + dim], np.float32(cen))
                np.testing.assert_array_equal(row[12 : 12 + dim], np.float32(v))
                np.testing.assert_array_equal(row[15:18], np.float32(w))
