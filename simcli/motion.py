"""Prescribed rigid motion of colliders (host side, no Taichi).

A collider is written in the scene at its pose at t = 0 (its *body frame*). Its motion maps a body
point ``x0`` to the world point ``x(t) = R(t) (x0 - p) + p + d(t)`` where ``p`` is the pivot (the
collider's centre unless given), ``R(t)`` a rotation and ``d(t)`` a translation with ``d(0) = 0``
and ``R(0) = I`` for constant motion (keyframes and CSV files give theirs). The velocity of the
collider's material at a world point ``x`` is ``v(t) + w(t) x (x - c(t))`` with ``c(t) = p + d(t)``
(the moving pivot), ``v = d'`` and ``w`` the angular velocity in the world frame.

Three ways of giving it (``motion:`` of a collider, see docs/SCENE_FORMAT.md section 5):

* constant: ``linear_velocity``, ``angular_velocity`` [rad/s] about ``pivot``;
* ``keyframes: {times, translate, rotate}``: piecewise linear translation and rotation (XYZ Euler angles
  in degrees, interpolated as quaternions along the shortest arc), held before the first and after the
  last key;
* ``file``: a CSV with columns t, x, y, z, qw, qx, qy, qz (translation and unit quaternion), piecewise
  linear like keyframes.

In 2D the rotation is about z: ``angular_velocity`` has one component (or three, x and y zero) and
``rotate`` one angle (or three, x and y zero); vectors have two components.

Solvers use :meth:`Motion.pose`, which gives ``R`` (dim x dim), the moving pivot ``c``, the pivot ``p``,
``v`` (dim) and ``w`` (3, the z component alone matters in 2D).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

CSV_COLUMNS = ("t", "x", "y", "z", "qw", "qx", "qy", "qz")


# ----------------------------------------------------------------- quaternions (w, x, y, z)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def quat_conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_from_axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    n = float(np.linalg.norm(axis))
    if n == 0.0 or angle == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    a = np.asarray(axis, float) / n
    s = math.sin(0.5 * angle)
    return np.array([math.cos(0.5 * angle), a[0] * s, a[1] * s, a[2] * s])


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    return quat_from_axis_angle(r, float(np.linalg.norm(r)))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, float)
    if q[0] < 0:
        q = -q
    s = float(np.linalg.norm(q[1:]))
    if s < 1e-15:
        return 2.0 * q[1:]
    angle = 2.0 * math.atan2(s, q[0])
    return q[1:] / s * angle


def quat_from_euler_xyz_deg(angles: np.ndarray) -> np.ndarray:
    """Extrinsic rotations about x, then y, then z (R = Rz Ry Rx), angles in degrees."""
    ax, ay, az = (math.radians(float(a)) for a in angles)
    qx = quat_from_axis_angle(np.array([1.0, 0, 0]), ax)
    qy = quat_from_axis_angle(np.array([0, 1.0, 0]), ay)
    qz = quat_from_axis_angle(np.array([0, 0, 1.0]), az)
    return quat_mul(qz, quat_mul(qy, qx))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Shortest-arc interpolation: q0 exp(s log(q0^-1 q1))."""
    dq = quat_mul(quat_conj(q0), q1)
    r = quat_to_rotvec(dq)
    return quat_mul(q0, quat_from_rotvec(s * r))


# ----------------------------------------------------------------------- motion


@dataclass
class Pose:
    """The collider's pose and velocity at one time (world frame, ``dim`` components)."""

    R: np.ndarray  # (dim, dim) rotation
    c: np.ndarray  # (dim,) moving pivot p + d(t)
    p: np.ndarray  # (dim,) pivot in the body frame
    v: np.ndarray  # (dim,) velocity of the moving pivot
    w: np.ndarray  # (3,) angular velocity [rad/s]

    def to_world(self, x0: np.ndarray) -> np.ndarray:
        """Body-frame points (n, dim) -> world points."""
        return (np.asarray(x0) - self.p) @ self.R.T + self.c

    def to_body(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x) - self.c) @ self.R + self.p

    def velocity_at(self, x: np.ndarray) -> np.ndarray:
        """Velocity [m/s] of the collider's material at world points (n, dim)."""
        r = np.asarray(x, float) - self.c
        dim = self.c.shape[0]
        if dim == 2:
            wz = self.w[2]
            return self.v + wz * np.stack([-r[..., 1], r[..., 0]], axis=-1)
        return self.v + np.cross(self.w, r)


class Motion:
    """A prescribed rigid motion: ``pose(t)``. Built by :func:`make_motion` from a collider's ``motion``."""

    def __init__(
        self,
        dim: int,
        pivot: np.ndarray,
        times: np.ndarray,
        d: np.ndarray,
        q: np.ndarray,
        v: np.ndarray | None = None,
        w: np.ndarray | None = None,
    ):
        self.dim = dim
        self.pivot = np.asarray(pivot, float)  # (3,)
        self.times = times  # keyframe times (k,), or None for constant motion
        self.d = d  # (k, 3) translations, or None
        self.q = q  # (k, 4) quaternions, or None
        self.v = v  # constant linear velocity (3,), or None
        self.w = w  # constant angular velocity (3,), or None
        self._flat = None  # (w, v, pivot) as floats, for constant_pose_flat

    @property
    def constant(self) -> bool:
        return self.times is None

    def _full(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(R 3x3, d (3,), v (3,), w (3,)) at time t."""
        if self.constant:  # one implementation with the per-substep upload's (constant_pose_flat)
            R9, c, v, w = self.constant_pose_flat(t)
            return np.array(R9).reshape(3, 3), np.array(v) * t, np.array(v), np.array(w)  # (pivot + v t = c)
        ts = self.times
        if t <= ts[0] or len(ts) == 1:
            return quat_to_matrix(self.q[0]), self.d[0].copy(), np.zeros(3), np.zeros(3)
        if t >= ts[-1]:
            return quat_to_matrix(self.q[-1]), self.d[-1].copy(), np.zeros(3), np.zeros(3)
        i = int(np.searchsorted(ts, t, side="right")) - 1
        i = min(max(i, 0), len(ts) - 2)
        t0, t1 = ts[i], ts[i + 1]
        T = t1 - t0
        s = (t - t0) / T
        d = (1 - s) * self.d[i] + s * self.d[i + 1]
        v = (self.d[i + 1] - self.d[i]) / T
        q0, q1 = self.q[i], self.q[i + 1]
        q = slerp(q0, q1, s)
        # q(t) = q0 exp(s r) with r the body-frame rotation vector of the segment: world w = R0 r / T
        r = quat_to_rotvec(quat_mul(quat_conj(q0), q1))
        w = quat_to_matrix(q0) @ r / T
        return quat_to_matrix(q), d, v, w

    def constant_pose_flat(self, t: float) -> tuple[list, list, list, list]:
        """A constant motion's pose at time t as plain floats (R row-major 3x3, moving pivot, v, w): the
        rotation vector's quaternion, normalised, then its matrix (``quat_to_matrix(quat_from_rotvec(w t))``
        to f64 round-off), without numpy's per-call cost on 3-vectors. ``pose`` uses it too, so the
        per-substep upload (ColliderPoses.set_time), CPIC's poses and the host's are the same numbers."""
        if self._flat is None:
            self._flat = (
                [float(x) for x in self.w],
                [float(x) for x in self.v],
                [float(x) for x in self.pivot],
            )
        (w0, w1, w2), (v0, v1, v2), (p0, p1, p2) = self._flat
        r0, r1, r2 = w0 * t, w1 * t, w2 * t
        n = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if n == 0.0:
            qw, qx, qy, qz = 1.0, 0.0, 0.0, 0.0
        else:
            sn = math.sin(0.5 * n)
            qw, qx, qy, qz = math.cos(0.5 * n), r0 / n * sn, r1 / n * sn, r2 / n * sn
            m = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw, qx, qy, qz = qw / m, qx / m, qy / m, qz / m
        R = [
            1 - 2 * (qy * qy + qz * qz),
            2 * (qx * qy - qz * qw),
            2 * (qx * qz + qy * qw),
            2 * (qx * qy + qz * qw),
            1 - 2 * (qx * qx + qz * qz),
            2 * (qy * qz - qx * qw),
            2 * (qx * qz - qy * qw),
            2 * (qy * qz + qx * qw),
            1 - 2 * (qx * qx + qy * qy),
        ]
        return R, [p0 + v0 * t, p1 + v1 * t, p2 + v2 * t], [v0, v1, v2], [w0, w1, w2]

    def pose(self, t: float) -> Pose:
        R, d, v, w = self._full(float(t))
        n = self.dim
        return Pose(R=R[:n, :n].copy(), c=(self.pivot + d)[:n], p=self.pivot[:n].copy(), v=v[:n], w=w)


# ------------------------------------------------------------------ construction


class MotionError(ValueError):
    """A bad motion (message says what to change); ``path`` is the key path below the collider's motion."""

    def __init__(self, msg: str, path: tuple = ()):
        super().__init__(msg)
        self.path = path


RATE_LIMIT = (
    1.0e9  # [m/s] or [rad/s]: beyond it no step resolves the motion, and w t overflows the pose's angle
)


def _vec3(v, dim: int, what: str, path: tuple, angle: bool = False, rate: bool = False) -> np.ndarray:
    v = [float(x) for x in v]
    if not all(math.isfinite(x) for x in v):  # (an infinite rate was a traceback in the pose's sin)
        raise MotionError(f"{what}: every component must be a finite number (got {v})", path)
    if rate and any(abs(x) > RATE_LIMIT for x in v):  # (a rate of 1e300 overflowed w t in the pose's sin)
        raise MotionError(
            f"{what}: components of at most {RATE_LIMIT:g} in magnitude (got {v}): no time step resolves a "
            "faster motion",
            path,
        )
    if dim == 2:
        if angle:
            if len(v) == 1:
                return np.array([0.0, 0.0, v[0]])
            if len(v) == 3:
                if v[0] != 0 or v[1] != 0:
                    raise MotionError(f"{what}: in 2D a rotation is about z only (x and y must be 0)", path)
                return np.array(v)
            raise MotionError(f"{what}: expected 1 component (about z) in 2D (got {len(v)})", path)
        if len(v) != 2:
            raise MotionError(f"{what}: expected 2 components for dim 2 (got {len(v)})", path)
        return np.array(v + [0.0])
    if len(v) != 3:
        raise MotionError(f"{what}: expected 3 components for dim 3 (got {len(v)})", path)
    return np.array(v)


def read_motion_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times, translations (k, 3), quaternions (k, 4)) of a motion CSV; MotionError with the line."""
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise MotionError(f"cannot read motion file {path}: {e.strerror or e}", ("file",)) from None
    rows = [r for r in csv.reader(text.splitlines()) if r and any(c.strip() for c in r)]
    if not rows:
        raise MotionError(
            f"motion file {path} is empty; it needs a header {','.join(CSV_COLUMNS)}", ("file",)
        )
    header = [c.strip().lower() for c in rows[0]]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise MotionError(
            f"{path}:1: missing column(s) {', '.join(missing)}; the header must name "
            f"{', '.join(CSV_COLUMNS)}",
            ("file",),
        )
    idx = [header.index(c) for c in CSV_COLUMNS]
    data = []
    for ln, r in enumerate(rows[1:], start=2):
        try:
            data.append([float(r[i]) for i in idx])
        except (ValueError, IndexError):
            raise MotionError(
                f"{path}:{ln}: expected numbers in columns {', '.join(CSV_COLUMNS)}", ("file",)
            ) from None
    if not data:
        raise MotionError(f"{path}: no data rows below the header", ("file",))
    a = np.array(data)
    if not np.all(np.isfinite(a)):
        raise MotionError(f"{path}: non-finite value", ("file",))
    t = a[:, 0]
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if len(bad):
        raise MotionError(
            f"{path}:{int(bad[0]) + 3}: times must increase (t = {t[bad[0] + 1]:g} after {t[bad[0]]:g})",
            ("file",),
        )
    q = a[:, 4:8]
    nq = np.linalg.norm(q, axis=1)
    if np.any(nq < 1e-9):
        ln = int(np.nonzero(nq < 1e-9)[0][0]) + 2
        raise MotionError(f"{path}:{ln}: quaternion qw, qx, qy, qz is zero", ("file",))
    return t, a[:, 1:4], q / nq[:, None]


def make_motion(motion: Any, dim: int, centre: np.ndarray, scene_dir: Path | None = None) -> Motion:
    """The Motion of a collider's ``motion`` model (simcli.scene.models.Motion); ``centre`` (dim,) is the
    default pivot. MotionError (with the key path below ``motion``) for bad input."""
    pivot = centre if motion.pivot is None else motion.pivot
    piv = _vec3(pivot, dim, "pivot", ("pivot",))
    if motion.keyframes is not None:
        kf = motion.keyframes
        t = np.array([float(x) for x in kf.times])
        bad = np.nonzero(np.diff(t) <= 0)[0]
        if len(bad):
            i = int(bad[0]) + 1
            raise MotionError(
                f"keyframe times must increase (times[{i}] = {t[i]:g} after {t[i - 1]:g})",
                ("keyframes", "times", i),
            )
        k = len(t)
        tr = kf.translate if kf.translate is not None else [[0.0] * dim] * k
        ro = kf.rotate if kf.rotate is not None else [[0.0] * (1 if dim == 2 else 3)] * k
        for key, lst in (("translate", tr), ("rotate", ro)):
            if len(lst) != k:
                raise MotionError(f"{key} needs one entry per time ({k}), got {len(lst)}", ("keyframes", key))
        d = np.array([_vec3(x, dim, "translate", ("keyframes", "translate", i)) for i, x in enumerate(tr)])
        q = np.array(
            [
                quat_from_euler_xyz_deg(_vec3(x, dim, "rotate", ("keyframes", "rotate", i), angle=True))
                for i, x in enumerate(ro)
            ]
        )
        return Motion(dim, piv, t, d, q)
    if motion.file is not None:
        path = Path(motion.file)
        if not path.is_absolute() and scene_dir is not None:
            path = Path(scene_dir) / path
        t, d, q = read_motion_csv(path)
        if dim == 2:
            if np.any(np.abs(d[:, 2]) > 0):
                raise MotionError(f"{path}: z must be 0 in 2D", ("file",))
            rv = np.array([quat_to_rotvec(x) for x in q])
            if np.any(np.abs(rv[:, :2]) > 1e-9):
                raise MotionError(f"{path}: in 2D the rotations must be about z (qx = qy = 0)", ("file",))
        return Motion(dim, piv, t, d, q)
    lv = motion.linear_velocity if motion.linear_velocity is not None else [0.0] * dim
    av = motion.angular_velocity if motion.angular_velocity is not None else [0.0] * (1 if dim == 2 else 3)
    return Motion(
        dim,
        piv,
        None,
        None,
        None,
        v=_vec3(lv, dim, "linear_velocity", ("linear_velocity",), rate=True),
        w=_vec3(av, dim, "angular_velocity", ("angular_velocity",), angle=True, rate=True),
    )


def collider_centre(c: Any, dim: int) -> np.ndarray:
    """The default pivot of a collider model: the box's centre, the sphere's or cylinder's centre, the
    plane's point."""
    if c.type == "Box":
        return 0.5 * (np.asarray(c.lower, float) + np.asarray(c.upper, float))
    if c.type == "Plane":
        return np.asarray(c.point, float)
    if c.type == "Mesh":  # the file's origin after the transform (where scale and rotate act)
        return np.asarray(c.translate, float)
    return np.asarray(c.center, float)


def collider_motion(c: Any, dim: int, scene_dir: Path | None = None) -> Motion | None:
    if getattr(c, "motion", None) is None:
        return None
    return make_motion(c.motion, dim, collider_centre(c, dim), scene_dir)


def sample_times(motion: Motion, t_end: float, n: int = 200) -> np.ndarray:
    ts = np.linspace(0.0, t_end, n)
    if not motion.constant:
        ts = np.union1d(ts, motion.times[(motion.times >= 0) & (motion.times <= t_end)])
    return ts
