"""All the rigid bodies of a scene and their time integration, between the families' substeps.

A rigid body is a moving, named collider (simcli.colliders) whose pose comes from here: every family that
honours moving named colliders (MPM, PBD, FEM, SPH; not SF) reads its pose each
substep, lets its material meet it, and adds the impulse the material gave it to the collider's load.
After the families' substep the runner calls :meth:`RigidWorld.step`: the loads of that substep are read
(and cleared) from every family, then gravity, the loads, wall and body-body contacts and the held degrees
of freedom give the new velocities (semi-implicit Euler: velocities first, then the position and the
quaternion with the new ones), and the next substep's poses follow.

The registry: every solver asks :func:`world_for` (through simcli.colliders.collider_specs /
collider_motions) and gets the same bodies for the same scene object, so all families and the runner
share one state. :func:`release` drops it at the end of a run.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simcli.motion import quat_from_rotvec, quat_mul, quat_to_matrix

from .body import RigidBodyModel
from .contact import (
    bounding_radius,
    collider_contacts,
    find_contacts,
    solve_contacts,
    surface_points,
    wall_points,
)

_WORLDS: dict[int, tuple[Any, RigidWorld]] = {}


def world_for(scene: Any, scene_dir: Any = None) -> RigidWorld | None:
    """The scene's rigid bodies (one shared instance per scene object); None without any. ``scene_dir``:
    Mesh bodies' files are relative to it (the first caller builds the world)."""
    if not getattr(scene, "rigid_bodies", None):
        return None
    hit = _WORLDS.get(id(scene))
    if hit is not None and hit[0] is scene:
        return hit[1]
    w = RigidWorld(scene, scene_dir)
    _WORLDS[id(scene)] = (scene, w)
    return w


def release(scene: Any) -> None:
    _WORLDS.pop(id(scene), None)


def solver_poses(solver: Any):
    """The simcli.colliders.ColliderPoses a family reads its moving colliders from (None: it has none)."""
    return solver.collider_poses()


class RigidWorld:
    def __init__(self, scene: Any, scene_dir: Any = None):
        self.scene = scene
        self.scene_dir = scene_dir
        self._colliders = None  # (spec, motion) of the scene's colliders, built at the first step
        self.collider_source = None  # () -> those pairs (simcli.colliders sets it)
        self.dim = dim = int(scene.sim.dim)
        self.bodies = [RigidBodyModel(rb, dim, scene, scene_dir) for rb in scene.rigid_bodies]
        self.n_colliders = len(scene.colliders)  # rigid body k is collider n_colliders + k of every family
        self.gravity = np.asarray(scene.sim.gravity_vec, float)[:dim]
        lo, hi = scene.domain.bounds(dim)
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.pts = [surface_points(b.spec, dim) for b in self.bodies]
        for b in self.bodies:  # what the walls and the bodies' broad phase test
            b.wall_pts = wall_points(b.spec, dim)
            b.reach = bounding_radius(b.spec, dim)
        nb = len(self.bodies)
        self.frame_load = np.zeros((nb, dim + 3))  # materials' impulse since the last frame
        self.frame_contact = np.zeros((nb, dim + 3))  # walls' and bodies' impulse since the last frame
        self.frame_time = 0.0
        self.t = 0.0
        self.substeps = 0
        self.contacts_last = 0

    # ------------------------------------------------------------------ specs
    def specs(self) -> list:
        return [b.spec for b in self.bodies]

    def motions(self) -> list:
        return [b.motion for b in self.bodies]

    def colliders(self) -> list:
        """(ColliderSpec, Motion or None) of the scene's colliders (not the bodies), for body-collider
        contact; built on first use by ``collider_source`` (set by simcli.colliders, which asks this world
        for the bodies' specs: rigid sits below it and imports no Taichi)."""
        if self._colliders is None:
            self._colliders = list(self.collider_source()) if self.collider_source is not None else []
        return self._colliders

    # ------------------------------------------------------------------ stepping
    def _loads(self, solvers) -> np.ndarray:
        dim = self.dim
        tot = np.zeros((len(self.bodies), dim + 3))
        rows = list(range(self.n_colliders, self.n_colliders + len(self.bodies)))
        for s in solvers:
            p = solver_poses(s)
            if p is None or not getattr(p, "any_named", False) or not hasattr(p, "load"):
                continue
            a = p.load.to_numpy()
            tot += a[rows]
            a[rows] = 0.0
            p.load.from_numpy(a)
        return tot

    def step(self, solvers, dt: float) -> None:
        """One substep of every body, after the families' substep [t, t + dt]."""
        dim = self.dim
        J = self._loads(solvers)
        for k, b in enumerate(self.bodies):
            s = b.state
            v = s.v + J[k, :dim] / b.mass + self.gravity * dt
            Iinv = b.world_inertia_inv()
            L = J[k, dim:].copy()
            if dim == 3:  # gyroscopic term of Euler's equations, explicit
                R3 = quat_to_matrix(s.q)
                Iw = R3 @ b.inertia @ R3.T
                L -= np.cross(s.w, Iw @ s.w) * dt
            w = s.w + Iinv @ L
            v[b.lin_fixed] = b.v_hold[b.lin_fixed]
            w[b.ang_fixed] = b.w_hold[b.ang_fixed]
            s.v, s.w = v, w
        contacts = find_contacts(self.bodies, self.pts, self.lo, self.hi, dt)
        if self.n_colliders:
            contacts += collider_contacts(self.bodies, self.pts, self.colliders(), self.t, dt)
        self.contacts_last = len(contacts)
        C = solve_contacts(self.bodies, contacts, dt) if contacts else None
        for k, b in enumerate(self.bodies):
            s = b.state
            s.v[b.lin_fixed] = b.v_hold[b.lin_fixed]
            s.w[b.ang_fixed] = b.w_hold[b.ang_fixed]
            s.x = s.x + s.v * dt
            q = quat_mul(quat_from_rotvec(s.w * dt), s.q)
            s.q = q / np.linalg.norm(q)
            b.t = self.t + dt
        self.t += dt
        for b in self.bodies:
            s = b.state
            if not (np.isfinite(s.x).all() and np.isfinite(s.v).all() and np.isfinite(s.w).all()):
                from simcli.errors import NumericalError

                raise NumericalError(
                    f"numerical failure in rigid body '{b.name}' at t = {self.t:.6g} s: its state is not "
                    "finite "
                    "(the materials' load on it blew up). Every earlier frame is kept. To fix: lower sim.dt "
                    "or "
                    "use substeps: auto, make the body larger than a few cells or particles, or denser"
                )
        self.frame_load += J
        if C is not None:
            self.frame_contact += C
        self.frame_time += dt
        self.substeps += 1

    # ------------------------------------------------------------------ output
    def frame_values(self) -> dict[str, dict[str, np.ndarray]]:
        """Per body: position, orientation, velocity, angular_velocity, force and torque (from the
        materials, mean over the frame [N], [N m] about the centre of mass); resets the frame sums."""
        dim = self.dim
        out = {}
        span = self.frame_time
        for k, b in enumerate(self.bodies):
            a = self.frame_load[k] / span if span > 0 else np.zeros(dim + 3)
            b.last_force = a[:dim]
            b.last_torque = a[dim:]
            out[b.name] = {
                "position": b.state.x.copy(),
                "orientation": b.orientation_out(),
                "velocity": b.state.v.copy(),
                "angular_velocity": b.state.w.copy() if dim == 3 else b.state.w[2:3].copy(),
                "force": a[:dim].copy(),
                "torque": a[dim:].copy() if dim == 3 else a[dim + 2 : dim + 3].copy(),
            }
        self.frame_load[:] = 0.0
        self.frame_contact[:] = 0.0
        self.frame_time = 0.0
        return out

    def summary(self) -> dict:
        dim = self.dim
        out = {}
        for b in self.bodies:
            s = b.state
            out[b.name] = {
                "mass_kg": b.mass,
                "position_m": s.x.tolist(),
                "orientation": b.orientation_out().tolist(),
                "velocity_m_s": s.v.tolist(),
                "angular_velocity_rad_s": (s.w if dim == 3 else s.w[2:3]).tolist(),
                "force_N": np.asarray(b.last_force).tolist(),
                "torque_Nm": np.asarray(b.last_torque if dim == 3 else b.last_torque[2:3]).tolist(),
            }
        return out

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, np.ndarray]:
        st = {"t": np.array([self.t]), "frame_time": np.array([self.frame_time])}
        for k, b in enumerate(self.bodies):
            s = b.state
            st[f"{b.name}/x"] = s.x.copy()
            st[f"{b.name}/q"] = s.q.copy()
            st[f"{b.name}/v"] = s.v.copy()
            st[f"{b.name}/w"] = s.w.copy()
            st[f"{b.name}/load"] = self.frame_load[k].copy()
            st[f"{b.name}/contact"] = self.frame_contact[k].copy()
        return st

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        self.t = float(np.asarray(st["t"]).reshape(-1)[0])
        self.frame_time = float(np.asarray(st["frame_time"]).reshape(-1)[0])
        for k, b in enumerate(self.bodies):
            s = b.state
            s.x = np.asarray(st[f"{b.name}/x"], float).copy()
            s.q = np.asarray(st[f"{b.name}/q"], float).copy()
            s.v = np.asarray(st[f"{b.name}/v"], float).copy()
            s.w = np.asarray(st[f"{b.name}/w"], float).copy()
            self.frame_load[k] = np.asarray(st[f"{b.name}/load"], float)
            self.frame_contact[k] = np.asarray(st[f"{b.name}/contact"], float)
            b.t = self.t
