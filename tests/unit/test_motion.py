"""simcli.motion: prescribed rigid motion of colliders (host side, no Taichi)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simcli.motion import (
    MotionError,
    make_motion,
    quat_from_euler_xyz_deg,
    quat_from_rotvec,
    quat_to_matrix,
    read_motion_csv,
)
from simcli.scene.models import Motion as MotionModel


def _m(dim=3, centre=(0.0, 0.0, 0.0), **kw):
    return make_motion(MotionModel(**kw), dim, np.asarray(centre[:dim], float))


def test_constant_rotation_about_pivot_moves_points_on_circles_and_velocity_is_w_cross_r():
    m = _m(angular_velocity=[0, 0, math.pi], pivot=[1.0, 0.0, 0.0])
    p = m.pose(0.5)  # a quarter turn about z through (1, 0, 0)
    x = p.to_world(np.array([[2.0, 0.0, 0.0]]))[0]
    assert np.allclose(x, [1.0, 1.0, 0.0])
    assert np.allclose(p.to_body(x[None])[0], [2.0, 0.0, 0.0])
    assert np.allclose(p.velocity_at(x[None])[0], [-math.pi, 0.0, 0.0])


def test_constant_translation_and_rotation_combined():
    m = _m(linear_velocity=[1.0, 0, 0], angular_velocity=[0, 0, 2.0])
    p = m.pose(0.25)
    assert np.allclose(p.c, [0.25, 0, 0])
    assert np.allclose(p.velocity_at(p.c[None])[0], [1.0, 0, 0])  # the pivot moves with v alone
    # velocity is the time derivative of the world position of a body point (finite difference)
    x0 = np.array([[0.3, -0.2, 0.1]])
    h = 1e-6
    fd = (m.pose(0.25 + h).to_world(x0) - m.pose(0.25 - h).to_world(x0)) / (2 * h)
    assert np.allclose(p.velocity_at(p.to_world(x0)), fd, atol=1e-6)


def test_keyframes_interpolate_translation_linearly_and_rotation_as_quaternions():
    m = _m(
        keyframes={
            "times": [0, 1, 2],
            "translate": [[0, 0, 0], [1, 0, 0], [1, 0, 0]],
            "rotate": [[0, 0, 0], [0, 0, 90], [0, 0, 90]],
        }
    )
    p = m.pose(0.5)
    assert np.allclose(p.c, [0.5, 0, 0])
    assert np.allclose(p.R, quat_to_matrix(quat_from_euler_xyz_deg([0, 0, 45])))
    assert np.allclose(p.w, [0, 0, math.pi / 2])
    assert np.allclose(m.pose(5.0).c, [1, 0, 0]) and np.allclose(m.pose(5.0).w, 0)  # held after the last key
    x0 = np.array([[0.2, 0.1, 0.0]])
    h = 1e-6
    fd = (m.pose(0.7 + h).to_world(x0) - m.pose(0.7 - h).to_world(x0)) / (2 * h)
    assert np.allclose(m.pose(0.7).velocity_at(m.pose(0.7).to_world(x0)), fd, atol=1e-6)


def test_keyframe_rotation_velocity_matches_finite_difference_for_a_tilted_start():
    m = _m(keyframes={"times": [0, 1], "rotate": [[30, 10, 0], [30, 10, 120]]})
    x0 = np.array([[0.5, 0.2, -0.3]])
    h = 1e-6
    fd = (m.pose(0.4 + h).to_world(x0) - m.pose(0.4 - h).to_world(x0)) / (2 * h)
    assert np.allclose(m.pose(0.4).velocity_at(m.pose(0.4).to_world(x0)), fd, atol=1e-6)


def test_2d_rotation_about_z():
    m = _m(dim=2, centre=(0.5, 0.5), angular_velocity=[math.pi])
    p = m.pose(1.0)  # half a turn about the centre
    assert np.allclose(p.to_world(np.array([[0.6, 0.5]]))[0], [0.4, 0.5])
    assert np.allclose(p.velocity_at(np.array([[0.6, 0.5]]))[0], [0.0, 0.1 * math.pi])
    with pytest.raises(MotionError, match="about z"):
        _m(dim=2, centre=(0.5, 0.5), angular_velocity=[1.0, 0.0, 1.0])


def test_keyframes_out_of_order_name_the_key():
    with pytest.raises(MotionError) as e:
        _m(keyframes={"times": [0, 2, 1]})
    assert e.value.path == ("keyframes", "times", 2)


def test_csv_motion_and_its_errors(tmp_path):
    f = tmp_path / "m.csv"
    f.write_text("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,1,0,0,0.7071067811865476,0,0,0.7071067811865476\n")
    m = _m(file=str(f))
    assert np.allclose(m.pose(0.5).c, [0.5, 0, 0])
    assert np.allclose(m.pose(1.0).R, quat_to_matrix(quat_from_euler_xyz_deg([0, 0, 90])))
    f.write_text("t,x,y,qw,qx,qy,qz\n0,0,0,1,0,0,0\n")
    with pytest.raises(MotionError, match="missing column.*z"):
        read_motion_csv(f)
    f.write_text("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n0,0,0,0,1,0,0,0\n")
    with pytest.raises(MotionError, match=r"m.csv:3: times must increase"):
        read_motion_csv(f)


def test_one_kind_of_motion():
    with pytest.raises(ValueError, match="one of"):
        MotionModel(linear_velocity=[1, 0, 0], file="m.csv")


@pytest.mark.parametrize("dim", [2, 3])
def test_constant_pose_flat_is_pose_in_plain_floats(dim):
    """The per-substep upload's scalar path (Motion.constant_pose_flat) gives pose()'s numbers exactly (pose
    uses it), and both are the rotation vector's quaternion matrix to f64 round-off."""
    if dim == 3:
        w3 = [1.0, -2.0, 4.0 * math.pi]
        m = _m(3, centre=(0.2, -0.1, 0.3), linear_velocity=[0.3, -0.2, 0.1], angular_velocity=w3)
    else:
        w3 = [0.0, 0.0, 4.0 * math.pi]
        m = _m(2, centre=(0.2, -0.1), linear_velocity=[0.3, -0.2], angular_velocity=[4.0 * math.pi])
    for t in np.linspace(0.0, 7.3, 211):
        p = m.pose(t)
        R9, c, v, w = m.constant_pose_flat(t)
        np.testing.assert_array_equal(np.array(R9).reshape(3, 3)[:dim, :dim], p.R)
        np.testing.assert_array_equal(c[:dim], p.c)
        np.testing.assert_array_equal(v[:dim], p.v)
        np.testing.assert_array_equal(w, p.w)
        R_ref = quat_to_matrix(quat_from_rotvec(np.array(w3) * t))[:dim, :dim]
        np.testing.assert_allclose(p.R, R_ref, rtol=0, atol=1e-13)  # 1 ulp of the angle (92 rad at 7.3 s)
