"""Rigid bodies in pictures: each body's surface (simcli.io.collider_vtk.collider_surface of its shape at
t = 0; a Mesh body's triangles as sim.h5 keeps them, /rigid_bodies/<name>/surface_points and
surface_triangles) moved to its pose at the frame (sim.h5 /rigid_bodies/<name>/position, /orientation)."""

from __future__ import annotations

import h5py
import numpy as np
import yaml

from simcli.io.collider_vtk import collider_surface
from simcli.motion import quat_to_matrix


def rigid_surfaces(run, k: int) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, world points (m, dim), cells) of every rigid body at frame k; [] without any."""
    from simcli.rigid.body import body_spec, morph_centre
    from simcli.rigid.config import RigidBody

    path = run.out / "sim.h5"
    out = []
    try:
        with h5py.File(path, "r", swmr=True) as f:
            if "rigid_bodies" not in f:
                return []
            scene = yaml.safe_load(f.attrs["scene"])
            dim = run.dim
            for d in scene.get("rigid_bodies") or []:
                rb = RigidBody.model_validate(d)
                g = f["rigid_bodies"].get(rb.name)
                if g is None or g["position"].shape[0] <= k:
                    continue
                if "surface_points" in g:  # a Mesh body: its triangles about the centre of mass
                    pts = np.asarray(g["surface_points"], float)
                    cells = np.asarray(g["surface_triangles"], np.int64)
                    centre = np.zeros(dim)
                else:
                    pts, cells = collider_surface(body_spec(rb, dim), dim, 1.0)
                    centre = morph_centre(rb.morph, dim)
                x = np.asarray(g["position"][k], float)
                o = np.asarray(g["orientation"][k], float)
                if dim == 2:
                    c, s = np.cos(o[0]), np.sin(o[0])
                    R = np.array([[c, -s], [s, c]])
                else:
                    R = quat_to_matrix(o / np.linalg.norm(o))
                out.append((rb.name, (pts - centre) @ R.T + x, cells))
    except (OSError, KeyError, ValueError):
        return []
    return out
