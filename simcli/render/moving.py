"""Colliders in prescribed motion in pictures: each moving collider's pose at the frame's time
(simcli.motion, the same prescription the solvers follow), applied to the shapes drawn at t = 0."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simcli.motion import Pose


def collider_poses(run) -> list:
    """A function t -> Pose (or None: still) for every collider of the run, in scene order."""
    from pydantic import TypeAdapter

    from simcli.motion import collider_motion
    from simcli.scene.models import Collider

    adapter = TypeAdapter(Collider)
    out = []
    for col in run.colliders:
        m = None
        if col.get("motion") is not None:
            try:
                model = adapter.validate_python({k: v for k, v in col.items() if not k.startswith("_")})
                scene_dir = col.get("_scene_dir")
                m = collider_motion(model, run.dim, Path(scene_dir) if scene_dir else None)
            except (ValueError, TypeError, OSError):
                m = None  # a collider this cannot read is drawn where it starts
        out.append(m.pose if m is not None else None)
    return out


def pose_points(pose: Pose | None, pts: np.ndarray) -> np.ndarray:
    """Points of the shape at t = 0 (..., dim) at the collider's pose."""
    if pose is None:
        return pts
    shape = pts.shape
    return pose.to_world(np.asarray(pts, float).reshape(-1, shape[-1])).reshape(shape)


def pose_outline_2d(pose: Pose | None, o):
    """A 2D outline of geometry.collider_outline_2d at the collider's pose (a rectangle turns into a
    polygon when it rotates)."""
    if pose is None or o is None:
        return o
    if o[0] == "circle":
        return ("circle", tuple(pose_points(pose, np.asarray(o[1], float)[None])[0]), o[2])
    if o[0] == "rect":
        (x0, y0), (x1, y1) = o[1], o[2]
        corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)
        return ("polygon", pose_points(pose, corners))
    if o[0] == "polygon":
        return ("polygon", pose_points(pose, np.asarray(o[1], float)))
    return o
