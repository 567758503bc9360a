"""Colliders in prescribed motion as moving solid boundaries of the stable-fluids grid, and the pressure
load on named colliders (host side, numpy; the collider geometry and motion of simcli.colliders and
simcli.motion, as every family uses).

* **Moving solids.** Before each substep the cells whose centre lies inside a collider at the substep's
  end pose (its body-frame signed distance at ``to_body(x)``) become solid: flags, face kinds, the
  Poisson diagonals of every multigrid level and the viscosity operator are recomputed (grid.py) and
  uploaded. A solid face (between a fluid and a solid cell) takes the normal velocity of the collider's
  surface there, ``(v + w x (x_f - c)) . e_d`` (the owning solid cell's collider), as its fixed value:
  the projection's boundary condition u . n = u_solid . n, so a moving obstacle pushes the fluid aside
  and the fluid follows it. A face that leaves the solid keeps the collider's velocity as its start.
  Still colliders keep the static code path (their faces are fixed at 0, as before).
* **Loads.** The force of the fluid's pressure on a named collider, ``F = sum_f rho p_f A_f n_f`` over
  its solid faces next to a fluid cell (``p`` the pressure the projection stored, kinematic p / rho, of
  the fluid cell; ``n_f`` the face normal pointing from the fluid into the solid; ``A_f`` the face area,
  per metre of depth in 2D), and its moment about the collider's moving pivot (taken at the face
  centres), summed as impulses over the substeps (p is phi / dt of each projection, so the sum is the
  momentum the projection gave the fluid at the solid faces, reversed). Viscous shear on the obstacle is
  not included (nor the viscosity operator's use of a moving solid's velocity: its faces count as still
  there).
"""

import numpy as np

from simcli.solvers.sf.grid import FLUID, SOLID_FACE, Layout


class SFColliders:
    def __init__(self, scene, layout: Layout, scene_dir=None) -> None:
        from simcli.colliders import collider_motions, collider_specs

        self.layout = L = layout
        self.dim = dim = L.dim
        self.specs = collider_specs(scene, dim, scene_dir)
        self.motions = collider_motions(scene, dim, scene_dir)
        self.any_moving = any(m is not None for m in self.motions)
        self.named = [k for k, c in enumerate(self.specs) if c.name is not None]
        self.rho = float(next(e for e in scene.entities if e.family == "SF").material.rho)
        self.x = np.stack([c.ravel() for c in L.cell_centres()], axis=1)
        self.acc: dict[str, np.ndarray] = {}  # impulses summed since the last collider_loads()

    def max_surface_speed(self, t: float) -> float:
        """Largest speed [m/s] of a moving collider's surface at time t (simcli.colliders.ColliderPoses's
        estimate; no Taichi field is allocated)."""
        from simcli.colliders import ColliderPoses

        return ColliderPoses(self.specs, self.motions, self.dim, None).max_surface_speed(t)

    def _pose(self, k: int, t: float):
        m = self.motions[k]
        return None if m is None else m.pose(t)

    def owner(self, t: float) -> np.ndarray:
        """Per cell (shape n): the index of the first collider holding the cell's centre at time t, -1
        for none."""
        from simcli.colliders import sdf_np

        own = np.full(len(self.x), -1, np.int32)
        for k, spec in enumerate(self.specs):
            p = self._pose(k, t)
            xb = self.x if p is None else p.to_body(self.x)
            own[(own < 0) & (sdf_np(spec, xb) < 0)] = k
        return own.reshape(self.layout.n)

    def _face_cells(self, own: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray]:
        """Owners of the left (I - e_d) and right (I) cells of every face of component d (faces 0 .. n_d
        along d), -1 outside the grid."""
        dim = self.dim
        pad = np.pad(own, [(1, 1) if a == d else (0, 0) for a in range(dim)], constant_values=-1)
        left = pad[tuple(slice(0, -1) if a == d else slice(None) for a in range(dim))]
        right = pad[tuple(slice(1, None) if a == d else slice(None) for a in range(dim))]
        return left, right

    def face_velocity(self, own: np.ndarray, t: float) -> np.ndarray:
        """The fixed value of every solid face (padded face layout, shape (dim,) + n + 3): the owning
        collider's surface velocity component d at the face centre; 0 elsewhere and for still colliders."""
        L, dim = self.layout, self.dim
        out = np.zeros((dim,) + tuple(c + 3 for c in L.n))
        for d in range(dim):
            left, right = self._face_cells(own, d)
            k_face = np.where(left >= 0, left, right)
            xf = np.stack([c.ravel() for c in L.face_centres(d)], axis=1)
            u = np.zeros(k_face.size)
            kf = k_face.ravel()
            for k in range(len(self.specs)):
                p = self._pose(k, t)
                sel = kf == k
                if p is None or not sel.any():
                    continue
                u[sel] = p.velocity_at(xf[sel])[:, d]
            out[(d,) + tuple(slice(1, 1 + s) for s in k_face.shape)] = u.reshape(k_face.shape)
        return out

    def loads(self, own: np.ndarray, pressure: np.ndarray, t: float) -> dict[str, np.ndarray]:
        """Named collider -> (dim + 3) force [N] and moment about its moving pivot [N m] of the fluid's
        pressure (``pressure``: kinematic, shape n) on its solid faces next to fluid cells."""
        L, dim = self.layout, self.dim
        fluid = L.flags[(slice(1, -1),) * dim] == FLUID
        out = {self.specs[k].name: np.zeros(dim + 3) for k in self.named}
        for d in range(dim):
            area = float(np.prod([L.dx[a] for a in range(dim) if a != d]))
            left, right = self._face_cells(own, d)
            kind = L.kinds[d][tuple(slice(1, 1 + s) for s in left.shape)]
            pf = np.pad(pressure * fluid, [(1, 1) if a == d else (0, 0) for a in range(dim)])
            fl = np.pad(fluid, [(1, 1) if a == d else (0, 0) for a in range(dim)])
            p_left = pf[tuple(slice(0, -1) if a == d else slice(None) for a in range(dim))]
            p_right = pf[tuple(slice(1, None) if a == d else slice(None) for a in range(dim))]
            f_left = fl[tuple(slice(0, -1) if a == d else slice(None) for a in range(dim))]
            f_right = fl[tuple(slice(1, None) if a == d else slice(None) for a in range(dim))]
            xf = np.stack([c.ravel() for c in L.face_centres(d)], axis=1)
            for k in self.named:
                # fluid on the left, collider k on the right: the pressure pushes the collider along +e_d
                a = (kind == SOLID_FACE) & f_left & (right == k)
                b = (kind == SOLID_FACE) & f_right & (left == k)
                fd = self.rho * area * (np.where(a, p_left, 0.0) - np.where(b, p_right, 0.0))
                sel = (a | b).ravel()
                if not sel.any():
                    continue
                F = np.zeros((int(sel.sum()), dim))
                F[:, d] = fd.ravel()[sel]
                load = out[self.specs[k].name]
                load[:dim] += F.sum(axis=0)
                p = self._pose(k, t)
                c = np.asarray(self.specs[k].centre or np.zeros(dim), float) if p is None else p.c[:dim]
                r = xf[sel] - c
                if dim == 2:
                    load[dim + 2] += float(np.sum(r[:, 0] * F[:, 1] - r[:, 1] * F[:, 0]))
                else:
                    load[dim:] += np.cross(r, F).sum(axis=0)
        return out
