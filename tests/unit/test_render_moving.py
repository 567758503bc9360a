"""simcli render draws a collider in prescribed motion where it is at the frame's time (simcli.motion),
not where it started."""

from types import SimpleNamespace

import numpy as np

from simcli.render.geometry import collider_outline_2d, collider_triangles
from simcli.render.moving import collider_poses, pose_outline_2d, pose_points


def _run(colliders, dim):
    return SimpleNamespace(colliders=colliders, dim=dim, times=np.array([0.0, 0.25, 0.5]))


def test_a_turning_box_is_drawn_turned_and_a_still_one_where_it_is():
    paddle = {
        "type": "Box",
        "lower": [0.1, 0.09],
        "upper": [0.3, 0.11],
        "motion": {"angular_velocity": [np.pi]},
    }
    wall = {"type": "Box", "lower": [0.0, 0.0], "upper": [0.05, 0.05]}
    poses = collider_poses(_run([paddle, wall], 2))
    assert poses[1] is None
    p = poses[0](0.5)  # a quarter turn about its centre (0.2, 0.1)
    o = pose_outline_2d(p, collider_outline_2d(paddle, [0, 0], [1, 1]))
    assert o[0] == "polygon"
    pts = o[1]
    np.testing.assert_allclose(pts.min(axis=0), [0.19, 0.0], atol=1e-12)
    np.testing.assert_allclose(pts.max(axis=0), [0.21, 0.2], atol=1e-12)
    assert pose_outline_2d(None, collider_outline_2d(wall, [0, 0], [1, 1]))[0] == "rect"


def test_a_translating_sphere_in_3d_moves_with_its_velocity():
    ball = {
        "type": "Sphere",
        "center": [0.0, 0.0, 0.5],
        "radius": 0.1,
        "motion": {"linear_velocity": [1, 0, 0]},
    }
    (pose,) = collider_poses(_run([ball], 3))
    t0 = collider_triangles(ball, [-1, -1, 0], [1, 1, 1])
    t1 = pose_points(pose(0.25), t0)
    np.testing.assert_allclose(t1.reshape(-1, 3).mean(axis=0), [0.25, 0.0, 0.5], atol=1e-9)
    np.testing.assert_allclose(t1 - t0, np.broadcast_to([0.25, 0, 0], t0.shape), atol=1e-12)
