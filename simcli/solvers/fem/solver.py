"""FEM solver: linear tetrahedra, explicit (symplectic Euler) or implicit (backward Euler, Newton-PCG).

Every FEM entity is meshed at construction (``mesh.py``); the meshes are concatenated into one
vertex and one element array. Element forces are computed per element into a buffer and gathered
per vertex through a vertex -> (element, corner) adjacency list: no atomics, deterministic.

Lumped masses: each vertex gets a quarter of the mass of every adjacent tetrahedron (Genesis
divides by element mass instead).
"""

import math
from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.geometry.regions import points_in_regions, points_in_shape
from simcli.geometry.tetmesh import boundary_faces, mesh_for_entity, signed_volumes
from simcli.scene.output_fields import FIELDS
from simcli.solvers.base import Body, FrameStats, Solver, frame_stats_per_body, upload_state_array
from simcli.solvers.fem.models import LAWS, lame_for
from simcli.solvers.taichi_funcs import make_body_frame_stats

with stdout_to_stderr():
    import taichi as ti

OUTPUT_FIELDS = FIELDS["FEM"]  # the Taichi-free table validate checks (simcli/scene/output_fields.py)


def _active_factor(m) -> float:
    """FEM.Muscle: the P-wave modulus grows by at most stiffness x max|a| (explicit stability)."""
    if getattr(m, "type", "") != "FEM.Muscle":
        return 1.0
    return 1.0 + m.active_stiffness * m.max_activation() / (m.lam + 2.0 * m.mu)


class FEMSolver(Solver):
    family = "fem"
    # per element (cell data in .vtu, sim.h5 and XDMF); the *_nodal fields are volume-weighted vertex means
    cell_fields = ("von_mises", "J", "elastic_energy")

    def __init__(self, scene: Any, bodies: list[Body], scene_dir=None) -> None:
        super().__init__(scene, bodies)
        self.scene_dir = scene_dir  # collider motion files are relative to it
        if scene.sim.dim != 3:
            raise ValueError("FEM entities need a 3D scene (sim.dim: 3)")
        self.opts = scene.solvers.fem
        # implicit and backward_euler are the same integrator; implicit_midpoint shares its Newton solve
        self.implicit = self.opts.integrator != "explicit"
        self.midpoint = self.opts.integrator == "implicit_midpoint"
        self.entities = [e for e in scene.entities if e.family == "FEM"]
        # tet4 (linear) or tet10 (quadratic: simcli/solvers/fem/tet10.py, edge midpoints appended per entity)
        self.element = getattr(self.opts, "element", "tet4")
        self.tet10 = self.element == "tet10"
        xs, ts, self.offsets, self.toffsets = [], [], [0], [0]
        self.materials, mids, self.models = [], [], []
        t10s, self._edge_lookup, self.n_corner = [], [], []
        for e in self.entities:
            m = mesh_for_entity(e, self.opts, scene_dir)
            if self.tet10:
                from simcli.solvers.fem import tet10

                x10, t10 = tet10.quadratic_nodes(m.x, m.tets)
                self._edge_lookup.append(tet10.edge_node_lookup(t10, m.x.shape[0]))
                self.n_corner.append(m.x.shape[0])
                t10s.append(t10 + self.offsets[-1])
                m = type(m)(x10, m.tets, m.source)  # corner tets over the nodes (corners keep their indices)
            ts.append(m.tets + self.offsets[-1])
            xs.append(m.x)
            self.offsets.append(self.offsets[-1] + m.x.shape[0])
            self.toffsets.append(self.toffsets[-1] + m.tets.shape[0])
            if e.material not in self.materials:
                self.materials.append(e.material)
            mids.append(np.full(m.tets.shape[0], self.materials.index(e.material), np.int32))
        self.x0 = np.concatenate(xs)
        self.tets = np.concatenate(ts).astype(np.int64)
        self.mid = np.concatenate(mids)
        self.n, self.m = self.x0.shape[0], self.tets.shape[0]
        # kernel elements: tet4 its tetrahedra (nc = 4 corners); tet10 its quadrature points (4 per element,
        # nc = 10 nodes each; tet10.prepare)
        self.mk, self.nc = self.m, 4
        if self.tet10:
            self.tets10 = np.concatenate(t10s).astype(np.int64)
        self.models = []
        for mat in self.materials:
            if mat.model not in self.models:
                self.models.append(mat.model)
        self._index = {e.name: k for k, e in enumerate(self.entities)}
        self._prepare_host()
        self._built = False
        self.time = 0.0
        self.stats = {"newton": [], "pcg": [], "ls_halvings": 0, "newton_capped": 0, "pcg_capped": 0}

    # ---------------------------------------------------------------- host side
    def _prepare_host(self) -> None:
        x, T = self.x0, self.tets
        vol = signed_volumes(x, T)
        self.vol0 = vol
        Dm = np.stack([x[T[:, 1]] - x[T[:, 0]], x[T[:, 2]] - x[T[:, 0]], x[T[:, 3]] - x[T[:, 0]]], axis=2)
        self.B = np.linalg.inv(Dm)
        rho = np.array([float(self.materials[k].rho) for k in self.mid])
        if self.tet10:
            from simcli.solvers.fem import tet10

            mass = tet10.lumped_mass(self.tets10, vol, rho, self.n)  # HRZ (tet10.py)
        else:
            mass = np.zeros(self.n)
            for a in range(4):
                np.add.at(mass, T[:, a], 0.25 * rho * vol)
        self.mass = mass
        # adjacency vertex -> element corners (e * 4 + a)
        flat = T.reshape(-1)
        order = np.argsort(flat, kind="stable")
        self.adj = order.astype(np.int32)
        self.adj_start = np.concatenate([[0], np.cumsum(np.bincount(flat, minlength=self.n))]).astype(
            np.int32
        )
        # velocities, fixed components, prescribed velocity, dead loads
        v = np.zeros((self.n, 3))
        free = np.ones((self.n, 3))
        vfix = np.zeros((self.n, 3))
        fext = np.zeros((self.n, 3))
        self.warnings = []
        for k, e in enumerate(self.entities):
            lo, hi = self.offsets[k], self.offsets[k + 1]
            xe = x[lo:hi]
            if e.velocity is not None:
                v[lo:hi] = np.asarray(e.velocity, dtype=np.float64)
            if e.material.angular_velocity is not None:
                w = np.asarray(e.material.angular_velocity, dtype=np.float64)
                c = (self.mass[lo:hi, None] * xe).sum(0) / self.mass[lo:hi].sum()
                v[lo:hi] += np.cross(w[None, :], xe - c)
            held = points_in_regions(e.fixed_regions, xe)
            free[lo:hi][held] = 0.0
            v[lo:hi][held] = 0.0
            if e.fixed_regions and not held.any():
                self.warnings.append(f"{e.name}: fixed region holds no vertex")
            tk = T[self.toffsets[k] : self.toffsets[k + 1]] - lo
            faces = None
            for bc in e.material.boundary_conditions:
                inside = points_in_shape(bc.region, xe)
                if bc.traction is not None:
                    if faces is None:
                        faces = boundary_faces(tk, xe)
                    sel = faces[inside[faces].all(axis=1)]
                    if len(sel) == 0:
                        self.warnings.append(f"{e.name}: traction region holds no boundary face")
                    area = 0.5 * np.linalg.norm(
                        np.cross(xe[sel[:, 1]] - xe[sel[:, 0]], xe[sel[:, 2]] - xe[sel[:, 0]]), axis=1
                    )
                    if self.tet10:  # a quadratic triangle's consistent load: t A / 3 on each edge node
                        from simcli.solvers.fem.tet10 import face_edge_nodes

                        sel = face_edge_nodes(sel, self._edge_lookup[k], self.n_corner[k])
                    for a in range(3):
                        np.add.at(
                            fext[lo:hi], sel[:, a], (area / 3.0)[:, None] * np.asarray(bc.traction)[None, :]
                        )
                    continue
                axes = ["xyz".index(c) for c in (bc.axes or ["x", "y", "z"])]
                idx = np.nonzero(inside)[0] + lo
                for c in axes:
                    free[idx, c] = 0.0
                    vel = 0.0 if bc.velocity is None else float(bc.velocity[c])
                    vfix[idx, c] = vel
                    v[idx, c] = vel
        self.v0, self.free, self.vfix, self.fext = v, free, vfix, fext
        self.xstart = x.copy()  # initial positions (rest shape x0 unless initial_stretch is given)
        for k, e in enumerate(self.entities):
            if e.material.initial_stretch is not None:
                lo, hi = self.offsets[k], self.offsets[k + 1]
                c = (self.mass[lo:hi, None] * x[lo:hi]).sum(0) / self.mass[lo:hi].sum()
                self.xstart[lo:hi] = c + (x[lo:hi] - c) * np.asarray(
                    e.material.initial_stretch, dtype=np.float64
                )
        # smallest element height (explicit stability) and mean edge length
        faces_area = []
        for i, j, k_ in ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)):
            faces_area.append(
                0.5 * np.linalg.norm(np.cross(x[T[:, j]] - x[T[:, i]], x[T[:, k_]] - x[T[:, i]]), axis=1)
            )
        height = 3.0 * vol / np.max(np.stack(faces_area), axis=0)
        self.h_min = float(height.min())
        self.c_p = max(
            math.sqrt((m.E * (1 - m.nu) / ((1 + m.nu) * (1 - 2 * m.nu))) / m.rho * _active_factor(m))
            for m in self.materials
        )
        self._prepare_muscles()
        self.edge = float(np.mean(np.linalg.norm(x[T[:, 1]] - x[T[:, 0]], axis=1)))
        self.extent = float(np.linalg.norm(x.max(axis=0) - x.min(axis=0)))
        self.Bk, self.volk, self.midk = self.B, self.vol0, self.mid  # the kernel elements' data (tet4)
        self.h_factor = 1.0
        if self.tet10:
            from simcli.solvers.fem import tet10

            tet10.prepare(self)  # quadrature points as kernel elements: Bk, volk, midk, adjacency
            self.h_factor = tet10.H_FACTOR  # explicit stability: the edge nodes shrink the node spacing

    def rest_diagonal_blocks(self) -> np.ndarray:
        """Per element corner a, the 3x3 diagonal block V (mu |g_a|^2 I + (mu + lam) g_a g_a^T) of the
        small-strain stiffness at rest (the materials' own Lame parameters), g_a the shape-function
        gradient. tet10: per quadrature point and node (tet10.rest_diagonal_blocks)."""
        if self.tet10:
            from simcli.solvers.fem import tet10

            return tet10.rest_diagonal_blocks(self)
        G = np.concatenate([-self.B.sum(axis=1, keepdims=True), self.B], axis=1)  # (m, 4, 3): rows of B
        mu = np.array([self.materials[k].mu for k in self.mid])
        lam = np.array([self.materials[k].lam for k in self.mid])
        g2 = np.einsum("eai,eai->ea", G, G)
        blocks = mu[:, None, None, None] * g2[:, :, None, None] * np.eye(3) + (mu + lam)[
            :, None, None, None
        ] * np.einsum("eai,eaj->eaij", G, G)
        return (self.vol0[:, None, None, None] * blocks).reshape(-1, 3, 3)

    def _prepare_muscles(self) -> None:
        """FEM.Muscle: per element its group (first group whose region holds the rest centroid), fibre
        direction (rest frame, unit) and active stiffness; the groups' signals in global group order."""
        self.signals: list = []
        self.el_group = np.zeros(self.m, np.int32)
        self.el_fiber = np.zeros((self.m, 3))
        self.el_fiber[:, 2] = 1.0
        self.el_k = np.zeros(self.m)
        for k, e in enumerate(self.entities):
            mat = e.material
            if getattr(mat, "type", "") != "FEM.Muscle":
                continue
            lo, hi = self.toffsets[k], self.toffsets[k + 1]
            cen = self.x0[self.tets[lo:hi]].mean(axis=1)
            taken = np.zeros(hi - lo, bool)
            default = mat.fiber_direction if mat.fiber_direction is not None else [0.0, 0.0, 1.0]
            for grp in mat.group_list():
                d = np.asarray(
                    grp.fiber_direction if grp.fiber_direction is not None else default, np.float64
                )
                sel = ~taken & (points_in_regions(grp.regions, cen) if grp.regions else True)
                self.el_group[lo:hi][sel] = len(self.signals)
                self.el_fiber[lo:hi][sel] = d / np.linalg.norm(d)
                self.el_k[lo:hi][sel] = mat.active_stiffness
                taken |= sel
                if not sel.any():
                    self.warnings.append(f"{e.name}: muscle group {len(self.signals)} holds no element")
                self.signals.append(grp.actuation)
        self.has_muscle = bool(self.signals)
        self._last_act = None

    def _update_activation(self, t: float) -> None:
        if not self.has_muscle:
            return
        a = np.array([float(sig(t)) for sig in self.signals])
        if self._last_act is None or not np.array_equal(a, self._last_act):  # a constant one is uploaded once
            self.act_f.from_numpy(a.astype(self.npf))
            self._last_act = a

    # --------------------------------------------------------------------- build
    def build(self) -> None:
        if self._built:
            return
        f = ti.f64 if self.scene.sim.precision == "f64" else ti.f32
        self.f = f
        self.npf = np.float64 if f == ti.f64 else np.float32
        n, m = self.n, self.mk  # kernel elements (tet10: quadrature points); tet_f holds the corner tets
        nc = self.nc
        V3 = lambda k: ti.Vector.field(3, f, shape=k)  # noqa: E731
        self.x, self.v, self.xr = V3(n), V3(n), V3(n)
        self.free_f, self.vfix_f, self.fext_f = V3(n), V3(n), V3(n)
        self.mass_f = ti.field(f, shape=n)
        self.tet_f = ti.Vector.field(4, ti.i32, shape=self.m)
        self.B_f = ti.Matrix.field(3, 3, f, shape=m)
        self.vol_f = ti.field(f, shape=m)
        self.mid_f = ti.field(ti.i32, shape=m)
        self.fe = V3(nc * m)
        self.adj_f = ti.field(ti.i32, shape=nc * m)
        self.adj_start_f = ti.field(ti.i32, shape=n + 1)
        nm = len(self.materials)
        self.mat_mu = ti.field(f, shape=nm)
        self.mat_lam = ti.field(f, shape=nm)
        # the materials' own Lame parameters (Rayleigh stiffness damping: beta x the small-strain stiffness)
        self.mat_mu0 = ti.field(f, shape=nm)
        self.mat_lam0 = ti.field(f, shape=nm)
        self.mat_law = ti.field(ti.i32, shape=nm)
        self.gravity = ti.Vector.field(3, f, shape=())
        nb = len(self.entities)
        self.body_off = ti.field(ti.i32, shape=nb + 1)
        self.stat_speed = ti.field(f, shape=nb)
        self.stat_bad = ti.field(ti.i32, shape=nb)
        self.out_vm = ti.field(f, shape=n)
        self.out_J = ti.field(f, shape=n)
        self.el_vm = ti.field(f, shape=m)
        self.el_J = ti.field(f, shape=m)
        self.el_E = None  # per element elastic energy V psi(F) [J]: allocated when first asked for (probes)
        mm = m if self.has_muscle else 1
        self.el_group_f = ti.field(ti.i32, shape=mm)
        self.el_fiber_f = V3(mm)
        self.el_k_f = ti.field(f, shape=mm)
        self.act_f = ti.field(f, shape=max(1, len(self.signals)))
        if self.has_muscle:
            self.el_group_f.from_numpy(self.el_group)
            self.el_fiber_f.from_numpy(self.el_fiber.astype(self.npf))
            self.el_k_f.from_numpy(self.el_k.astype(self.npf))

        npf = self.npf
        self.x.from_numpy(self.xstart.astype(npf))
        self.xr.from_numpy(self.x0.astype(npf))
        self.v.from_numpy(self.v0.astype(npf))
        self.free_f.from_numpy(self.free.astype(npf))
        self.vfix_f.from_numpy(self.vfix.astype(npf))
        self.fext_f.from_numpy(self.fext.astype(npf))
        self.mass_f.from_numpy(self.mass.astype(npf))
        self.tet_f.from_numpy(self.tets.astype(np.int32))
        self.B_f.from_numpy(self.Bk.astype(npf))
        self.vol_f.from_numpy(self.volk.astype(npf))
        self.mid_f.from_numpy(self.midk)
        self.adj_f.from_numpy(self.adj)
        self.adj_start_f.from_numpy(self.adj_start)
        mus, lams = [], []
        for mat in self.materials:
            mu, lam = lame_for(mat.model, mat.mu, mat.lam)
            mus.append(mu)
            lams.append(lam)
        self.mat_mu.from_numpy(np.array(mus, npf))
        self.mat_lam.from_numpy(np.array(lams, npf))
        self.mat_mu0.from_numpy(np.array([mat.mu for mat in self.materials], npf))
        self.mat_lam0.from_numpy(np.array([mat.lam for mat in self.materials], npf))
        self.mat_law.from_numpy(np.array([self.models.index(mt.model) for mt in self.materials], np.int32))
        self.gravity[None] = [float(c) for c in self.scene.sim.gravity_vec]
        self.body_off.from_numpy(np.array(self.offsets, np.int32))
        self._make_common()
        # moving and named colliders: pose per substep, loads (compiled only when a collider needs them)
        from simcli.colliders import ColliderPoses, collider_motions, collider_specs

        self.poses = ColliderPoses(
            collider_specs(self.scene, 3, self.scene_dir),
            collider_motions(self.scene, 3, self.scene_dir),
            3,
            self.f,
        )
        self.poses.allocate()
        if self.implicit:
            from simcli.solvers.fem.implicit import ImplicitIntegrator

            self.integrator = ImplicitIntegrator(self)
        else:
            from simcli.solvers.fem.explicit import ExplicitIntegrator

            self.integrator = ExplicitIntegrator(self)
        self._built = True
        self._version = 0
        self.frame_check()

    # ------------------------------------------------------------ shared funcs
    def _make_common(self) -> None:
        laws = [LAWS[k] for k in self.models]
        nl = len(laws)
        x, tet, B, mid, mat_mu, mat_lam, mat_law = (
            self.x,
            self.tet_f,
            self.B_f,
            self.mid_f,
            self.mat_mu,
            self.mat_lam,
            self.mat_law,
        )

        @ti.func
        def deformation(e, xf: ti.template()):
            t = tet[e]
            x0 = xf[t[0]]
            Ds = ti.Matrix.cols([xf[t[1]] - x0, xf[t[2]] - x0, xf[t[3]] - x0])
            return Ds @ B[e]

        self.deformation_plus = self.corner_grad = None
        if self.tet10:  # per quadrature point, 10 nodes (tet10.py)
            from simcli.solvers.fem import tet10

            deformation, self.deformation_plus, scatter10, self.corner_grad = tet10.make_funcs(self)

        has_muscle = self.has_muscle
        el_group, el_fiber, el_k, act = self.el_group_f, self.el_fiber_f, self.el_k_f, self.act_f

        @ti.func
        def active_energy(e, F):
            """FEM.Muscle: energy k a (|F f0|^2 - 1) / 2 of the active fibre stress."""
            Ff = F @ el_fiber[e]
            return el_k[e] * act[el_group[e]] * 0.5 * (Ff.dot(Ff) - 1.0)

        @ti.func
        def active_pk1(e, F):
            """FEM.Muscle: first Piola-Kirchhoff active stress k a (F f0) f0^T."""
            f0 = el_fiber[e]
            return el_k[e] * act[el_group[e]] * (F @ f0).outer_product(f0)

        @ti.func
        def active_dP(e, dF):
            """dP of the active stress for the increment dF, activation clamped at 0 (positive
            semi-definite)."""
            ka = ti.max(el_k[e] * act[el_group[e]], 0.0)
            f0 = el_fiber[e]
            return ka * (dF @ f0).outer_product(f0)

        @ti.func
        def law_call(e, F, which: ti.template()):
            """energy or pk1 of element e's law (compiled only for the laws present), plus the active
            fibre stress of FEM.Muscle elements when the scene has any."""
            k = mid[e]
            mu, lam = mat_mu[k], mat_lam[k]
            r = ti.static(getattr(laws[0], which))(F, mu, lam)
            if ti.static(nl > 1):
                lid = mat_law[k]
                for q in ti.static(range(1, nl)):
                    if lid == q:
                        r = ti.static(getattr(laws[q], which))(F, mu, lam)
            if ti.static(has_muscle):
                if ti.static(which == "energy"):
                    r += active_energy(e, F)
                else:
                    r += active_pk1(e, F)
            return r

        @ti.func
        def law_hessian(e, F):
            k = mid[e]
            mu, lam = mat_mu[k], mat_lam[k]
            U, V, Hs, ls, lt = laws[0].hessian(F, mu, lam, True)
            if ti.static(nl > 1):
                lid = mat_law[k]
                for q in ti.static(range(1, nl)):
                    if lid == q:
                        U, V, Hs, ls, lt = laws[q].hessian(F, mu, lam, True)
            return U, V, Hs, ls, lt

        @ti.func
        def scatter_columns(e, H):
            """Corner vectors of an element: columns of H (corners 1..3) and minus their sum (corner 0)."""
            c1 = ti.Vector([H[0, 0], H[1, 0], H[2, 0]])
            c2 = ti.Vector([H[0, 1], H[1, 1], H[2, 1]])
            c3 = ti.Vector([H[0, 2], H[1, 2], H[2, 2]])
            self.fe[4 * e] = -(c1 + c2 + c3)
            self.fe[4 * e + 1] = c1
            self.fe[4 * e + 2] = c2
            self.fe[4 * e + 3] = c3

        @ti.func
        def gather(i):
            s = ti.Vector.zero(float, 3)
            for q in range(self.adj_start_f[i], self.adj_start_f[i + 1]):
                k = self.adj_f[q]
                if k < 0:  # never: keeps the loop scalar (solvers/sph/neighbours.py, Scalar pair loops)
                    break
                s += self.fe[k]
            return s

        self.deformation, self.law_call, self.law_hessian = deformation, law_call, law_hessian
        self.active_dP = active_dP
        self.scatter_columns, self.gather = scatter_columns, gather
        if self.tet10:
            self.scatter_columns = scatter10

        nb = len(self.entities)
        v, stat_speed, stat_bad, body_off = self.v, self.stat_speed, self.stat_bad, self.body_off
        n, m, m_el, nc = self.n, self.mk, self.m, self.nc
        f64 = self.f == ti.f64
        f = self.f
        vol, out_vm, out_J, el_vm, el_J = self.vol_f, self.out_vm, self.out_J, self.el_vm, self.el_J

        frame_stats = make_body_frame_stats(nb, body_off, x, v, stat_speed, stat_bad, f64)

        @ti.kernel
        def outputs():
            """Per element the von Mises Cauchy stress and J; per vertex their volume-weighted means over the
            adjacent elements."""
            for e in range(m):
                F = deformation(e, x)
                J = F.determinant()
                P = law_call(e, F, "pk1")
                s = P @ F.transpose()  # J x Cauchy stress
                if J > 0:
                    s /= J
                p = s.trace() / 3.0
                dev = s - p * ti.Matrix.identity(float, 3)
                vm = ti.sqrt(1.5 * (dev * dev).sum())
                el_vm[e] = vm
                el_J[e] = J
                self.fe[nc * e] = ti.Vector([vm * vol[e], J * vol[e], vol[e]])
            for i in range(n):
                acc = ti.Vector.zero(float, 3)
                for q in range(self.adj_start_f[i], self.adj_start_f[i + 1]):
                    k = self.adj_f[q]
                    if k < 0:  # never: keeps the loop scalar (solvers/sph/neighbours.py, Scalar pair loops)
                        break
                    acc += self.fe[nc * (k // nc)]
                out_vm[i] = acc[0] / acc[2]
                out_J[i] = acc[1] / acc[2]

        hmin_cur = self.hmin_cur = ti.field(f, shape=())

        @ti.kernel
        def min_height():
            """Smallest current element height 3 |V| / largest face area (explicit stability)."""
            hmin_cur[None] = 1e30
            for e in range(m_el):
                t = self.tet_f[e]
                a, b, c, d = x[t[0]], x[t[1]], x[t[2]], x[t[3]]
                V = ti.abs((b - a).dot((c - a).cross(d - a))) / 6.0
                A = (
                    ti.max(
                        ti.max((c - b).cross(d - b).norm(), (c - a).cross(d - a).norm()),
                        ti.max((b - a).cross(d - a).norm(), (b - a).cross(c - a).norm()),
                    )
                    * 0.5
                )
                ti.atomic_min(hmin_cur[None], 3.0 * V / ti.max(A, 1e-30))

        self._frame_stats, self._outputs, self._min_height = frame_stats, outputs, min_height

    # -------------------------------------------------------------- stepping
    def substep(self, dt: float) -> None:
        # activation at the substep's start (explicit), end (backward Euler's forces are at t + dt) or middle
        # (implicit midpoint's forces are at t + dt / 2)
        if self.midpoint:
            self._update_activation(self.time + 0.5 * dt)
        else:
            self._update_activation(self.time + (dt if self.implicit else 0.0))
        if self.poses.needed:  # collider poses of this substep (host, no sync)
            self.poses.set_time(self.time, dt)
        self.integrator.substep(dt, self.time)
        self.time += dt
        self._version += 1

    def frame_check(self) -> dict[str, FrameStats]:
        self._frame_stats()
        return frame_stats_per_body(
            [e.name for e in self.entities], self.stat_speed.to_numpy(), self.stat_bad.to_numpy()
        )

    def stable_dt(self, horizon: float = 0.0) -> float:
        """Explicit: cfl x (smallest current element height, at least a quarter of the rest one) / (P-wave
        speed + largest vertex speed). Implicit: unlimited."""
        if self.implicit:
            return math.inf
        self._frame_stats()
        self._min_height()
        vmax = float(np.max(self.stat_speed.to_numpy()))
        h = max(float(self.hmin_cur[None]), 0.25 * self.h_min)
        # tet10: the corner tetrahedra's height times tet10.H_FACTOR (1.0 for tet4: the same float)
        return self.opts.cfl * min(h, self.h_min) * self.h_factor / (self.c_p + vmax)

    def collider_loads(self) -> dict[str, np.ndarray]:
        """Named collider -> impulse [N s] and its moment [N m s] the vertices gave it since the last call
        (explicit: the momentum the contact projection removed; implicit: the penalty's impulse and the
        friction's)."""
        return self.poses.loads_by_name() if self._built else {}

    def length_scale(self) -> float:
        # explicit: a vertex crossing more than two elements per substep is a blow-up; implicit
        # backward Euler is not limited by element size: only a body crossing itself is
        return self.extent if self.implicit else self.edge

    # ---------------------------------------------------------------- output
    def entity_kind(self, name: str) -> str:
        return "tets"

    def entity_cells(self, name: str):
        k = self._index[name]
        return self.tets[self.toffsets[k] : self.toffsets[k + 1]] - self.offsets[k]

    def entity_size(self, name: str) -> int:
        k = self._index[name]
        return int(self.offsets[k + 1] - self.offsets[k])

    def owns(self, name: str) -> bool:
        return name in self._index

    def default_fields(self, name: str) -> list[str]:
        return ["position", "velocity", "displacement", "von_mises", "J"]

    def output_fields(self) -> dict[str, tuple[int, str]]:
        return {
            "position": (3, "m"),
            "velocity": (3, "m/s"),
            "displacement": (3, "m"),
            "von_mises": (1, "Pa"),
            "J": (1, "1"),
            "von_mises_nodal": (1, "Pa"),
            "J_nodal": (1, "1"),
            "mass": (1, "kg"),
            "elastic_energy": (1, "J"),
        }

    def entity_arrays(self, name: str, fields: list[str]) -> dict[str, np.ndarray]:
        k = self._index[name]
        lo, hi = self.offsets[k], self.offsets[k + 1]
        out = {}
        if any(f in ("von_mises", "J", "von_mises_nodal", "J_nodal") for f in fields):
            self._outputs()
        tlo, thi = self.toffsets[k], self.toffsets[k + 1]
        for fld in fields:
            if fld == "elastic_energy":
                out[fld] = np.array(self._elastic_energy()[tlo:thi])
                continue
            if fld in self.cell_fields:
                a = (self.el_vm if fld == "von_mises" else self.el_J).to_numpy()
                if self.tet10:  # per element: the mean over its quadrature points (equal weights)
                    a = a.reshape(self.m, -1).mean(axis=1)
                out[fld] = np.array(a[tlo:thi])
                continue
            if fld == "position":
                a = self.x.to_numpy()
            elif fld == "velocity":
                a = self.v.to_numpy()
            elif fld == "displacement":
                a = self.x.to_numpy() - self.x0
            elif fld == "von_mises_nodal":
                a = self.out_vm.to_numpy()
            elif fld == "J_nodal":
                a = self.out_J.to_numpy()
            elif fld == "mass":
                a = self.mass
            else:
                raise KeyError(f"unknown FEM output field {fld!r}; known: {', '.join(OUTPUT_FIELDS)}")
            out[fld] = np.array(a[lo:hi])
        return out

    def _elastic_energy(self) -> np.ndarray:
        """Per element the stored energy V_e psi(F_e) [J] of its law at the current positions (FEM.Muscle:
        with the active fibre energy; Rayleigh damping stores none). Compiled on first use."""
        if self.el_E is None:
            self.el_E = ti.field(self.f, shape=self.mk)
            el_E, vol, x, m = self.el_E, self.vol_f, self.x, self.mk
            deformation, law_call = self.deformation, self.law_call

            @ti.kernel
            def energy():
                for e in range(m):
                    el_E[e] = vol[e] * law_call(e, deformation(e, x), "energy")

            self._energy_k = energy
        self._energy_k()
        if self.tet10:  # per element: the sum over its quadrature points
            return self.el_E.to_numpy().reshape(self.m, -1).sum(axis=1)
        return self.el_E.to_numpy()

    def positions(self) -> np.ndarray:
        return self.x.to_numpy().astype(np.float64)

    # ----------------------------------------------------------------- state
    def get_state(self) -> dict[str, np.ndarray]:
        return {"x": self.x.to_numpy(), "v": self.v.to_numpy(), "time": np.array([self.time])}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        for key, fld in (("x", self.x), ("v", self.v)):
            upload_state_array(fld, state, key, (self.n, 3), self.npf, "FEM")
        if "time" in state:
            self.time = float(np.asarray(state["time"]).reshape(-1)[0])
        self._version += 1

    def counts(self) -> dict[str, int]:
        return {"vertices": self.n, "tets": self.m}  # tet10: vertices are its nodes, tets its elements

    def info(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "integrator": self.opts.integrator,
            "models": list(self.models),
            "vertices": self.n,
            "tets": self.m,
            "mass_lumping": "HRZ (tet10)" if self.tet10 else "1/4 of each adjacent tet",
            **({"element": "tet10", "nodes": self.n} if self.tet10 else {}),
            "smallest_element_height_m": self.h_min,
            "warnings": self.warnings,
        }
        s = self.stats
        if self.implicit and s["newton"]:
            nw, pc = np.asarray(s["newton"]), np.asarray(s["pcg"])
            d.update(
                newton_iterations_per_step={"mean": float(nw.mean()), "max": int(nw.max())},
                pcg_iterations_per_step={"mean": float(pc.mean()), "max": int(pc.max())},
                pcg_iterations_per_newton=float(pc.sum() / max(1, nw.sum())),
                line_search_halvings=s["ls_halvings"],
                newton_capped=s["newton_capped"],
                pcg_capped=s["pcg_capped"],
                newton_stagnated=s.get("stagnated", 0),
                **({"midpoint_fallbacks": s.get("midpoint_fallbacks", 0)} if self.midpoint else {}),
                steps_measured=len(nw),
            )
        return d
