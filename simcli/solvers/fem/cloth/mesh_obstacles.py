"""`type: Mesh` and `type: Box` colliders for FEM.Cloth, the IPC way (Li et al. 2020): the collider's own
triangles join the cloth's in one ipctk collision mesh as obstacle vertices (indices n .. n + m - 1 after the
n cloth vertices) whose positions are prescribed, so the barrier, the lagged friction and the continuous
collision check treat cloth-collider point-triangle and edge-edge pairs exactly as the cloth's own (no
signed-distance grid).

* Static colliders: their vertices stay where the scene puts them (the file, scaled, rotated, translated).
* Moving colliders (simcli.motion: constant linear/angular velocity about a pivot, keyframes, CSV): within a
  Newton step the obstacle vertices go on straight lines from their current positions to their pose at the
  step's end time (the trajectory ipctk's CCD checks); a step cut short by the CCD leaves them on that
  chord, which is where the solver keeps them (``ClothSolver.vobs``), so every accepted state is the one
  the CCD found intersection-free. A finished substep puts them exactly at pose(t).
* ipctk's static-obstacle filter keeps collider-collider pairs out of the broad phase.
* Loads: the contact potential's gradient on the obstacle vertices is the force the cloth puts on them
  (the barrier's and friction's reaction, exactly minus what the cloth receives); its impulse over each
  substep and moment about the collider's moving pivot go to ``collider_loads``.
* A `type: Box` collider enters as its 12 exact triangles (8 corners, outward faces; pivot its centre, as
  simcli.motion takes it): a convex signed distance per cloth vertex kept the vertices out of the box but
  not the box's edges out of the cloth's triangles (a sheet draped over a box edge was cut by it).
"""

from __future__ import annotations

import numpy as np

from simcli.motion import collider_centre, collider_motion

MESH_TYPES = ("Mesh", "Box")  # collider types whose exact triangles join the cloth's collision mesh

# the 12 outward triangles of a box from its corners numbered by bits (x: 1, y: 2, z: 4 set = upper side)
_BOX_TRIS = np.array(
    [
        [0, 2, 3], [0, 3, 1],  # z-
        [4, 5, 7], [4, 7, 6],  # z+
        [0, 1, 5], [0, 5, 4],  # y-
        [2, 6, 7], [2, 7, 3],  # y+
        [0, 4, 6], [0, 6, 2],  # x-
        [1, 3, 7], [1, 7, 5],  # x+
    ],
    np.int64,
)  # fmt: skip


def box_mesh(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """(8, 3) corners and (12, 3) outward triangles of the axis-aligned box [lower, upper]."""
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    V = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
    return V, _BOX_TRIS.copy()


class MeshObstacles:
    """Every `type: Mesh` and `type: Box` collider of a scene: obstacle vertices and triangles (numbered
    0 .. m-1)."""

    def __init__(self, scene, scene_dir=None):
        from simcli.geometry.mesh import load_mesh_morph

        self.index, self.names, self.friction, self.motions, self.centres = [], [], [], [], []
        vs, ts, off = [], [], [0]
        for i, c in enumerate(scene.colliders):
            if c.type not in MESH_TYPES:
                continue
            if c.type == "Box":
                bv, bt = box_mesh(c.lower, c.upper)
            else:
                mesh = load_mesh_morph(c, scene_dir)
                bv, bt = mesh.vertices, mesh.triangles
            self.index.append(i)
            self.names.append(getattr(c, "name", None))
            self.friction.append(float(c.friction))
            self.motions.append(collider_motion(c, 3, scene_dir))
            self.centres.append(collider_centre(c, 3))
            vs.append(np.asarray(bv, float))
            ts.append(np.asarray(bt, np.int64) + off[-1])
            off.append(off[-1] + len(bv))
        self.offsets = off
        self.V0 = np.concatenate(vs) if vs else np.zeros((0, 3))
        self.T = np.concatenate(ts) if ts else np.zeros((0, 3), np.int64)
        self.m = len(self.V0)
        self.moving = any(mo is not None for mo in self.motions)
        self.vertex_mu = (
            np.concatenate([np.full(off[k + 1] - off[k], self.friction[k]) for k in range(len(self.index))])
            if vs
            else np.zeros(0)
        )

    def __len__(self) -> int:
        return len(self.index)

    def positions(self, t: float | None) -> np.ndarray:
        """(m, 3) world positions of every obstacle vertex at time t (their pose at t = 0 for None)."""
        out = self.V0.copy()
        for k, mo in enumerate(self.motions):
            if mo is None or t is None:
                continue
            lo, hi = self.offsets[k], self.offsets[k + 1]
            out[lo:hi] = mo.pose(float(t)).to_world(self.V0[lo:hi])
        return out

    def pivots(self, t: float | None) -> list[np.ndarray]:
        """The point each collider's moment is taken about: its moving pivot at time t (its default
        pivot, the file's origin after the transform, when it does not move)."""
        out = []
        for k, mo in enumerate(self.motions):
            out.append(self.centres[k] if mo is None or t is None else np.asarray(mo.pose(float(t)).c, float))
        return out

    def loads(
        self, force: np.ndarray, x_obs: np.ndarray, t: float | None, dt: float
    ) -> dict[str, np.ndarray]:
        """Named collider -> (6,) impulse [N s] and its moment [N m s] over dt from per-vertex forces (m, 3)
        on the obstacle vertices at positions x_obs."""
        out = {}
        piv = self.pivots(t)
        for k, name in enumerate(self.names):
            if name is None:
                continue
            lo, hi = self.offsets[k], self.offsets[k + 1]
            f = force[lo:hi]
            J = dt * f.sum(axis=0)
            M = dt * np.cross(x_obs[lo:hi] - piv[k], f).sum(axis=0)
            out[name] = np.concatenate([J, M])
        return out


def blend_mu(a: float, b: float) -> float:
    """ipctk's friction blend for the combined mesh: obstacle vertices carry -(1 + mu) (a marker), cloth
    vertices the cloth's mu; a cloth-obstacle pair takes the collider's mu, a cloth-cloth pair the cloth's."""
    if a < 0:
        return -a - 1.0
    if b < 0:
        return -b - 1.0
    return 0.5 * (a + b)


def initial_problems(x: np.ndarray, t: np.ndarray, scene, scene_dir, dhat: float) -> list[str]:
    """Messages for a cloth (vertices x, triangles t) that starts intersecting, inside or within dhat of a
    Mesh or Box collider at its pose at t = 0 (located: the collider's index and the first point)."""
    from simcli.collider_mesh import mesh_distance
    from simcli.geometry.mesh import TriMesh, points_inside_mesh
    from simcli.solvers.fem.cloth.geometry import edge_triangle_intersections

    mo = MeshObstacles(scene, scene_dir)
    V = mo.positions(0.0)
    out = []
    n = len(x)
    for k, ci in enumerate(mo.index):
        typ = scene.colliders[ci].type
        lo, hi = mo.offsets[k], mo.offsets[k + 1]
        Vk = V[lo:hi]
        Tk = mo.T[(mo.T >= lo).all(axis=1) & (mo.T < hi).all(axis=1)] - lo
        X = np.concatenate([x, Vk])
        T = np.concatenate([t, Tk + n])
        hits = [
            h for h in edge_triangle_intersections(X, T) if (h[0][0] < n) == (h[1] >= len(t))
        ]  # a cloth edge through a collider triangle or a collider edge through a cloth triangle
        if hits:
            out.append(
                f"the cloth intersects colliders.{ci} ({typ}) at the start (near "
                f"{np.round(hits[0][2], 6).tolist()}); move the cloth or the collider apart"
            )
            continue
        vol = float(abs(np.einsum("ij,ij->i", Vk[Tk[:, 0]], np.cross(Vk[Tk[:, 1]], Vk[Tk[:, 2]])).sum()) / 6)
        ins = points_inside_mesh(TriMesh(Vk, Tk, vol, "collider"), x)
        if ins.any():
            out.append(
                f"{int(ins.sum())} cloth vertex(es) start inside colliders.{ci} ({typ}) (first at "
                f"{np.round(x[np.argmax(ins)], 6).tolist()}); the cloth must start outside it: move it"
            )
            continue
        # cloth vertices to the collider's triangles and collider vertices to the cloth's, each only where
        # the other's bounding box (grown by dhat) reaches (brute force within)
        near_x = np.all((x >= Vk.min(axis=0) - dhat) & (x <= Vk.max(axis=0) + dhat), axis=1)
        near_v = np.all((Vk >= x.min(axis=0) - dhat) & (Vk <= x.max(axis=0) + dhat), axis=1)
        xs, vs = x[near_x], Vk[near_v]
        d1 = mesh_distance(Vk, Tk, xs) if len(xs) else np.full(1, np.inf)
        d2 = mesh_distance(x, t, vs) if len(vs) else np.full(1, np.inf)
        if min(d1.min(), d2.min()) < dhat:
            p = xs[np.argmin(d1)] if d1.min() <= d2.min() else vs[np.argmin(d2)]
            out.append(
                f"the cloth starts closer than solvers.fem.contact_distance ({dhat:g} m) to colliders.{ci} "
                f"({typ}) (distance {min(d1.min(), d2.min()):.3g} m near {np.round(p, 6).tolist()}): move "
                "the cloth away"
            )
    return out
