"""One free rigid body on the host: mass and inertia from its shape, its state (centre of mass x, unit
quaternion q (w, x, y, z), velocity v, angular velocity w, world frame), and the collider record and the
motion object through which every family sees it (simcli.colliders.ColliderPoses: a rigid body is a
moving, named collider whose pose comes from here instead of a prescribed simcli.motion.Motion).

The body frame is the body's placement at t = 0: its collider spec is the morph as given (a Box
axis-aligned, a Cylinder along its axis, a Mesh its file scaled, rotated and translated), and the pose
maps it to the world with R(q) about the centre of mass. A Mesh body is the signed-distance grid of a
Mesh collider (simcli.collider_mesh), with its mass, centre of mass and inertia integrated exactly over
the closed polyhedron (:func:`mesh_mass_properties`); in 2D a closed polygon's (simcli.rigid.polygon).
No Taichi here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simcli.collider_spec import ColliderSpec
from simcli.motion import Pose, quat_from_rotvec, quat_mul, quat_to_matrix

DOF_INDEX = {"x": 0, "y": 1, "z": 2, "rx": 3, "ry": 4, "rz": 5}


def mass_properties(morph, rho: float, dim: int) -> tuple[float, np.ndarray]:
    """(mass [kg] (2D: per metre of depth), inertia tensor about the centre of mass in the body frame,
    3x3 [kg m^2]; 2D: only [2, 2] is used)."""
    if morph.type == "Box":
        lo, hi = (np.asarray(b, float)[:dim] for b in morph.bounds())
        s = hi - lo
        if dim == 2:
            m = rho * s[0] * s[1]
            return m, np.diag([0.0, 0.0, m * (s[0] ** 2 + s[1] ** 2) / 12.0])
        m = rho * float(np.prod(s))
        return m, np.diag(
            [m * (s[1] ** 2 + s[2] ** 2), m * (s[0] ** 2 + s[2] ** 2), m * (s[0] ** 2 + s[1] ** 2)]
        ) / 12.0
    if morph.type == "Sphere":
        r = float(morph.radius)
        if dim == 2:
            m = rho * math.pi * r * r
            return m, np.diag([0.0, 0.0, 0.5 * m * r * r])
        m = rho * 4.0 / 3.0 * math.pi * r**3
        return m, np.eye(3) * 0.4 * m * r * r
    if morph.type == "Cylinder":
        r, h = float(morph.radius), float(morph.height)
        m = rho * math.pi * r * r * h
        ax = "xyz".index(morph.axis)
        i_perp = m * (3 * r * r + h * h) / 12.0
        d = np.full(3, i_perp)
        d[ax] = 0.5 * m * r * r
        return m, np.diag(d)
    raise ValueError(f"rigid bodies take Box, Sphere, Cylinder or Mesh morphs, not {morph.type}")


def mesh_mass_properties(V: np.ndarray, T: np.ndarray, rho: float) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass [kg], centre of mass (3,) [m], inertia about it (3, 3) [kg m^2]) of the solid bounded by the
    closed, outward-oriented triangle surface (V, T) at density rho: the exact volume integrals of
    1, x and x x^T, summed over the signed tetrahedra (origin, a, b, c) of the faces (the divergence
    theorem; e.g. Eberly, "Polyhedral mass properties", 2002). The second moment of such a tetrahedron is
    det / 120 (a a^T + b b^T + c c^T + s s^T), s = a + b + c, det = a . (b x c) = 6 x its signed volume."""
    V = np.asarray(V, float)
    T = np.asarray(T, np.int64)
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    vol = float(det.sum()) / 6.0
    if not vol > 0:
        raise ValueError(f"the mesh encloses no positive volume ({vol:.3g} m^3): is it closed and outward?")
    ssum = a + b + c
    com = (det[:, None] * ssum).sum(axis=0) / (24.0 * vol)
    C = np.einsum("k,ki,kj->ij", det, a, a) + np.einsum("k,ki,kj->ij", det, b, b)
    C += np.einsum("k,ki,kj->ij", det, c, c) + np.einsum("k,ki,kj->ij", det, ssum, ssum)
    C = C / 120.0 - vol * np.outer(com, com)  # about the centre of mass
    inertia = rho * (np.trace(C) * np.eye(3) - C)
    return rho * vol, com, 0.5 * (inertia + inertia.T)


class _MeshModel:
    """The fields simcli.collider_mesh.build_sdf reads, from a rigid body's Mesh morph."""

    type = "Mesh"
    restitution = 0.0

    def __init__(self, rb):
        m = rb.morph
        self.file, self.scale, self.rotate, self.translate = m.file, m.scale, m.rotate, m.translate
        self.sdf_cell = getattr(rb, "sdf_cell", None)


def mesh_sdf(rb, scene=None, scene_dir=None):
    """The signed-distance grid (simcli.collider_mesh.MeshSDF, cached per file) of a Mesh rigid body."""
    from simcli.collider_mesh import build_sdf

    return build_sdf(_MeshModel(rb), scene, scene_dir)


def morph_centre(morph, dim: int) -> np.ndarray:
    if morph.type == "Box":
        lo, hi = morph.bounds()
        return 0.5 * (np.asarray(lo, float) + np.asarray(hi, float))[:dim]
    return np.asarray(morph.center, float)[:dim]


def body_spec(rb, dim: int) -> ColliderSpec:
    """The collider record of a rigid body (its shape at t = 0), moving and named."""
    m = rb.morph
    zeros = (0.0,) * dim
    centre = tuple(float(x) for x in morph_centre(m, dim))
    if m.type == "Box":
        lo, hi = m.bounds()
        return ColliderSpec(
            "Box",
            rb.boundary,
            0,
            tuple(lo[:dim]),
            tuple(hi[:dim]),
            0.0,
            0.0,
            rb.friction,
            True,
            rb.name,
            centre,
            rigid=True,
        )
    if m.type == "Sphere":
        return ColliderSpec(
            "Sphere",
            rb.boundary,
            0,
            tuple(m.center[:dim]),
            zeros,
            m.radius,
            0.0,
            rb.friction,
            True,
            rb.name,
            centre,
            rigid=True,
        )
    return ColliderSpec(
        "Cylinder",
        rb.boundary,
        "xyz".index(m.axis),
        tuple(m.center),
        zeros,
        m.radius,
        0.5 * m.height,
        rb.friction,
        True,
        rb.name,
        centre,
        rigid=True,
    )


def mesh_body_spec(rb, sdf, com: np.ndarray) -> ColliderSpec:
    """The collider record of a Mesh rigid body: its signed-distance grid (body frame = the pose at t = 0),
    a = the bounding box's centre and radius = half its diagonal (as a Mesh collider's), centre = the
    centre of mass (the pivot of its pose)."""
    lo, hi = sdf.bounds
    return ColliderSpec(
        "Mesh",
        rb.boundary,
        0,
        tuple(float(v) for v in 0.5 * (lo + hi)),
        (0.0,) * len(lo),
        0.5 * float(np.linalg.norm(hi - lo)),
        0.0,
        rb.friction,
        True,
        rb.name,
        tuple(float(v) for v in com),
        mesh=sdf,
        rigid=True,
    )


@dataclass
class BodyState:
    x: np.ndarray  # (dim,) centre of mass [m]
    q: np.ndarray  # (4,) unit quaternion w, x, y, z (2D: a rotation about z)
    v: np.ndarray  # (dim,) [m/s]
    w: np.ndarray  # (3,) [rad/s] (2D: only z)


class RigidBodyModel:
    """Mass, inertia, state and fixed degrees of freedom of one body."""

    def __init__(self, rb, dim: int, scene=None, scene_dir=None):
        self.cfg, self.name, self.dim = rb, rb.name, dim
        if rb.morph.type == "Mesh" and dim == 2:  # a closed polygon (simcli.rigid.polygon)
            from simcli.rigid.polygon import build_polygon_sdf, polygon_mass_properties

            sdf = build_polygon_sdf(rb, scene, scene_dir)
            self.mass, com, J = polygon_mass_properties(sdf.vertices, float(rb.rho))
            self.inertia = np.diag([0.0, 0.0, J])
            self.pivot = com
            self.spec = mesh_body_spec(rb, sdf, com)
        elif rb.morph.type == "Mesh":
            sdf = mesh_sdf(rb, scene, scene_dir)
            self.mass, com, self.inertia = mesh_mass_properties(sdf.vertices, sdf.triangles, float(rb.rho))
            self.pivot = com  # the centre of mass in the body frame
            self.spec = mesh_body_spec(rb, sdf, com)
        else:
            self.mass, self.inertia = mass_properties(rb.morph, float(rb.rho), dim)
            self.pivot = morph_centre(rb.morph, dim)  # the centre of mass in the body frame
            self.spec = body_spec(rb, dim)
        v0 = np.zeros(dim) if rb.velocity is None else np.asarray(rb.velocity, float)[:dim]
        w0 = np.zeros(3)
        if rb.angular_velocity is not None:
            a = np.asarray(rb.angular_velocity, float)
            if dim == 2:
                w0[2] = a[0]
            else:
                w0[:] = a[:3]
        self.state = BodyState(self.pivot.copy(), np.array([1.0, 0, 0, 0]), v0.copy(), w0)
        self.t = 0.0  # time of the state [s]
        # held DOFs: 0..dim-1 linear, 3..5 angular (2D: x, y, rz)
        self.lin_fixed = np.zeros(dim, bool)
        self.ang_fixed = np.zeros(3, bool)
        if dim == 2:
            self.ang_fixed[:2] = True
        for d in rb.fixed_dofs:
            k = DOF_INDEX[d]
            if k < 3:
                if k < dim:
                    self.lin_fixed[k] = True
            else:
                self.ang_fixed[k - 3] = True
        self.v_hold = v0.copy()
        self.w_hold = w0.copy()
        self.motion = RigidMotion(self)
        self.last_force = np.zeros(dim)  # [N] from the materials, mean over the last frame
        self.last_torque = np.zeros(3)

    # ---- kinematics
    def R(self) -> np.ndarray:
        return quat_to_matrix(self.state.q)[: self.dim, : self.dim]

    def world_inertia_inv(self) -> np.ndarray:
        R3 = quat_to_matrix(self.state.q)
        Iw = R3 @ self.inertia @ R3.T
        if self.dim == 2:
            out = np.zeros((3, 3))
            out[2, 2] = 1.0 / Iw[2, 2]
            return out
        return np.linalg.inv(Iw)

    def pose_at(self, t: float) -> Pose:
        """The pose at time t, extrapolated from the state at self.t with its current velocities."""
        s = self.state
        h = float(t) - self.t
        q = quat_mul(quat_from_rotvec(s.w * h), s.q) if h != 0.0 else s.q
        n = self.dim
        return Pose(
            R=quat_to_matrix(q)[:n, :n].copy(),
            c=s.x + s.v * h,
            p=self.pivot.copy(),
            v=s.v.copy(),
            w=s.w.copy(),
        )

    def orientation_out(self) -> np.ndarray:
        """sim.h5 orientation: quaternion (w, x, y, z); 2D: the angle about z [rad]."""
        q = self.state.q
        if self.dim == 2:
            return np.array([2.0 * math.atan2(q[3], q[0])])
        return q.copy()


class RigidMotion:
    """Looks like simcli.motion.Motion to the collider path: ``pivot`` (3,) and ``pose(t)``."""

    def __init__(self, body: RigidBodyModel):
        self.body = body
        p = np.zeros(3)
        p[: body.dim] = body.pivot
        self.pivot = p
        self.dim = body.dim
        self.constant = False

    def pose(self, t: float) -> Pose:
        return self.body.pose_at(t)
