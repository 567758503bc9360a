"""FEM.Cloth solver: backward Euler on the incremental potential, Newton with a sparse direct solve, a
line search whose every trial step is first limited by continuous collision detection (IPC, Li et al. 2020).

Per substep (dt), with x_n, v_n the start state and x^ = x_n + dt v_n + dt^2 g:
  Phi(x) = 1/2 |x - x^|_M^2 / dt^2 + W_elastic(x) + kappa B(x) + D_friction(x) + damping |x - x_n|_M^2 c/(2
  dt)
  B: the IPC log barrier on squared distances below dhat = solvers.fem.contact_distance, over the cloth's
     point-triangle and edge-edge pairs (ipctk: broad phase, distances, barrier derivatives, CCD) and over
     (vertex, collider or domain wall) pairs through the obstacle's exact signed distance; `type: Mesh`
     colliders' triangles and `type: Box` colliders' 12 are obstacle vertices/faces of the same ipctk
     collision mesh (mesh_obstacles.py).
  Newton: H p = -grad Phi on the free vertices (projected element Hessians; SuperLU factor, reused as a CG
     preconditioner within the substep, see _linear_solve); the step
     alpha starts at min(1, CCD), CCD: ipctk's additive CCD for the cloth against itself, conservative
     advancement alpha |p_i| <= 0.9 d_i for vertices against obstacles (their distances are 1-Lipschitz),
     then halves until Phi decreases. A full step whose energy drop says that Phi still falls steeply at
     alpha = 1 is expanded instead (doubling alpha, each trial CCD-limited, while Phi decreases; _expand).
     Every accepted state is therefore intersection-free.
  Lagged friction (Coulomb, IPC's smoothed f0 with eps_v = 1e-3 m/s) against obstacles, normal forces
     and tangent bases from x_n.
Host numpy/scipy in float64 whatever sim.precision says (the contact guarantees need it).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from simcli.solvers.base import Body, FrameStats, Solver, upload_state_array
from simcli.solvers.fem.cloth.checks import cholmod_available
from simcli.solvers.fem.cloth.model import ShellModel
from simcli.solvers.fem.cloth.obstacles import Obstacles
from simcli.solvers.fem.cloth.topology import cloth_mesh

EPS_V = 1.0e-3  # friction smoothing velocity [m/s]
_DEBUG = bool(__import__("os").environ.get("SIMCLI_CLOTH_DEBUG"))


class CholmodFactor:
    """CHOLMOD's supernodal Cholesky factor of an SPD matrix (cvxopt.cholmod: symbolic analysis with its
    default ordering, numeric LL^T), with ``solve(b)`` as SuperLU's factor has. Raises ArithmeticError when
    the matrix is not positive definite. ``limit``: a context factory holding its BLAS to the run's threads
    (blas_limit; None: the library's own)."""

    def __init__(self, H, limit=None) -> None:
        import contextlib

        import cvxopt
        import cvxopt.cholmod as cm
        import scipy.sparse as sp

        self._cvx, self._cm = cvxopt, cm
        self._limit = limit or contextlib.nullcontext
        low = sp.tril(H, format="csc")  # CHOLMOD reads the lower triangle (uplo L)
        n = low.shape[0]
        cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(low.indptr))
        A = cvxopt.spmatrix(
            cvxopt.matrix(np.ascontiguousarray(low.data, dtype=np.float64)),
            cvxopt.matrix(low.indices.astype(np.int64)),
            cvxopt.matrix(cols),
            (n, n),
        )
        with self._limit():
            self._F = cm.symbolic(A, uplo="L")
            cm.numeric(A, self._F)

    @staticmethod
    def blas_limit(threads: int):
        """A context factory that holds the BLAS libraries to ``threads`` (threadpoolctl; its controller,
        which scans the loaded libraries, is made once here: a fresh threadpool_limits per call cost ~1 ms,
        against ~0.03 ms)."""
        import cvxopt.cholmod  # noqa: F401 - loaded first, so that the controller sees its BLAS
        from threadpoolctl import ThreadpoolController

        ctl = ThreadpoolController()
        return lambda: ctl.limit(limits=threads, user_api="blas")

    def solve(self, b):
        X = self._cvx.matrix(np.asarray(b, dtype=np.float64))  # (a copy: solved in place)
        with self._limit():
            self._cm.solve(self._F, X)
        return np.asarray(X).ravel()


def _barrier(s, sh):
    """IPC barrier on squared distance s < sh: b, db/ds, d2b/ds2 (0 at and beyond sh)."""
    s = np.minimum(s, sh)
    r = np.log(s / sh)
    b = -((s - sh) ** 2) * r
    b1 = -2 * (s - sh) * r - (s - sh) ** 2 / s
    b2 = -2 * r - 4 * (s - sh) / s + (s - sh) ** 2 / s**2
    return b, b1, b2


class BodyLoads:
    """The part of simcli.colliders.ColliderPoses that simcli.rigid.world reads a family's loads from:
    ``load`` (rows: the scene's colliders, then the rigid bodies; impulse [N s] and its moment about the
    body's centre of mass [N m s]) with to_numpy / from_numpy, here a host array."""

    any_named = True

    def __init__(self, rows: int):
        self.a = np.zeros((rows, 6))
        self.load = self

    def to_numpy(self) -> np.ndarray:
        return self.a.copy()

    def from_numpy(self, a) -> None:
        self.a[:] = a


class ClothSolver(Solver):
    family = "fem_cloth"
    REUSE_CG_ITERS = 10  # CG iterations with the previous factor before refactoring (a few solves' cost)
    # relative residual of that CG: an inexact Newton direction (forcing term 1e-2, 100 x pcg_tol at most;
    # Dembo, Eisenstat and Steihaug 1982). Where Newton takes many steps it converges linearly (model
    # Hessian), so a 1 % direction error costs no Newton steps and saves most of the CG iterations and
    # refactorisations; the stopping tests are unchanged (see docs/FEM.md)
    REUSE_CG_RTOL = 1.0e-2
    # a Dirichlet step (prescribed motion still to make) the CCD cut below this: the next direction is solved
    # exactly (a fresh factor). An inexact direction lets a vertex deep in a moving collider's barrier lag
    # the collider by up to the CG's 1 % (its barrier stiffness dominates the residual's norm only where it
    # is active): the collider's CCD then stops it at 0.9 of a shrinking gap, Newton after Newton (the
    # fast-sphere hard case: the gap 2e-2 -> 2e-8 m over 24 steps, the sphere 1.1-2.3 ms behind schedule)
    STALL_ALPHA = 0.1
    # Line-search expansion (Nocedal & Wright 2006, Numerical Optimization, section 3.5: the bracketing phase
    # grows alpha while the curvature condition fails). With the projected Hessian the model's curvature
    # along a buckling mode is far above the energy's (the true one may be ~0 or negative), and full Newton
    # steps then converge linearly at ~3 % per step (the 32 x 32 sheet on the sphere: 50-step substeps,
    # residual 0.3 -> 0.09). The energy drop of the accepted full step tells: for Phi quadratic along p,
    # (Phi(x + p) - Phi(x)) / (g.p / 2) = 2 - c_true / c_model, so a ratio above EXPAND_RATIO means
    # Phi'(1) < (EXPAND_RATIO - 1) g.p (Phi still falling at more than half its initial slope) and the
    # step is doubled, CCD-limited, while Phi decreases, up to EXPAND_MAX (or twice the quadratic optimum
    # 1 / (2 - ratio)). An energy evaluation is ~5 % of a Newton step's cost.
    EXPAND_RATIO = 1.5
    EXPAND_MAX = 64.0
    cell_fields = ("strain", "stress")  # per triangle

    def __init__(self, scene: Any, bodies: list[Body], scene_dir=None) -> None:
        super().__init__(scene, bodies)
        self.scene_dir = scene_dir
        self.entities = [e for e in scene.entities if e.material.type == "FEM.Cloth"]
        self.opts = scene.solvers.fem
        self.dhat = float(self.opts.contact_distance)
        self.time = 0.0
        self.stats = {
            "substeps": 0,
            "newton_iterations": 0,
            "max_newton": 0,
            "contacts": 0,
            "max_contacts": 0,
        }
        self.stats.update(
            {
                "line_search_fail": 0,
                "expansions": 0,  # full steps the line search expanded (EXPAND_RATIO)
                "ccd_s": 0.0,
                "solve_s": 0.0,
                "pcg_capped": 0,
                "assemble_s": 0.0,
                "factorizations": 0,
                "pcg_reuse_iterations": 0,
            }
        )
        self.warnings: list[str] = []
        self._built = False
        self._tc = None

    # ----------------------------------------------------------------- build
    def build(self) -> None:
        import sys

        import ipctk

        from simcli.geometry.regions import points_in_regions

        # ipctk's broad phase and CCD run on its own (TBB) threads: no more than the run's (sim.threads,
        # clamped to what the machine allows, is what Taichi was given; docs/LIMITS.md). Without Taichi
        # started (the solver used alone, as in the benchmarks) ipctk keeps its pool.
        ti = sys.modules.get("taichi")  # (not imported: not started either)
        self._threads = None
        if ti is not None and ti.lang.impl.get_runtime().prog is not None:
            threads = getattr(ti.lang.impl.current_cfg(), "cpu_max_num_threads", 1)
            self._threads = max(1, int(threads or 1))
            ipctk.set_num_threads(self._threads)
        choice = self.opts.linear_solver
        self._cholmod = choice == "cholmod" or (choice == "auto" and cholmod_available())
        self._blas_limit = None  # CHOLMOD's BLAS held to the run's threads, as ipctk above
        if self._cholmod and self._threads is not None:
            self._blas_limit = CholmodFactor.blas_limit(self._threads)

        xs, ts, mu, lam, h, D, mass, fixed, offs = [], [], [], [], [], [], [], [], [0]
        so = []
        self.cells = {}
        for e in self.entities:
            x, t = cloth_mesh(e, self.scene_dir)
            mat = e.material
            self.cells[e.name] = t
            ts.append(t + offs[-1])
            xs.append(x)
            m = len(t)
            mu.append(np.full(m, mat.E / (2 * (1 + mat.nu))))
            lam.append(np.full(m, mat.E * mat.nu / (1 - mat.nu**2)))
            h.append(np.full(m, mat.thickness))
            D.append(np.full(m, mat.D))
            so.append(np.full(m, mat.bending_model == "shape_operator"))
            area = 0.5 * np.linalg.norm(np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]]), axis=1)
            mv = np.zeros(len(x))
            for a in range(3):
                np.add.at(mv, t[:, a], mat.rho * mat.thickness * area / 3.0)
            mass.append(mv)
            fixed.append(points_in_regions(e.fixed_regions, x) if e.fixed_regions else np.zeros(len(x), bool))
            offs.append(offs[-1] + len(x))
        self.offsets = offs
        self.tri_offsets = np.concatenate([[0], np.cumsum([len(t) for t in ts])]).tolist()
        self.index = {e.name: k for k, e in enumerate(self.entities)}
        X = np.concatenate(xs)
        T = np.concatenate(ts)
        self.X = X
        self.tris = T
        self.model = ShellModel(
            X,
            T,
            np.concatenate(mu),
            np.concatenate(lam),
            np.concatenate(h),
            np.concatenate(D),
            shape_operator=np.concatenate(so),
            pinned=np.concatenate(fixed),
        )
        self.mass = np.concatenate(mass)
        self._valence = np.maximum(np.bincount(T.ravel(), minlength=len(X)), 1).astype(float)
        self._inertia = None  # (set per substep)
        self._load_ramps = []  # (forces, ramp_time) of the tractions that grow with time
        self.fext = self._edge_loads(xs, ts, offs)
        self.fext_any = bool(np.any(self.fext)) or bool(self._load_ramps)
        self.fext_full = self.fext
        self.fixed = np.concatenate(fixed)
        self._build_pins(xs, offs)
        self.damp = np.concatenate(
            [np.full(offs[k + 1] - offs[k], e.material.damping) for k, e in enumerate(self.entities)]
        )
        self.mu_self = max((e.material.friction for e in self.entities), default=0.0)
        self.n = len(X)
        self.x = X.copy()
        self.v = np.zeros_like(X)
        for k, e in enumerate(self.entities):
            if e.velocity is not None:
                self.v[offs[k] : offs[k + 1]] = np.asarray(e.velocity, float)
        self.v[self.fixed] = 0.0
        if self.moving_pins:
            self.v[self.pin_idx] = self._pin_velocity(0.0)
        self.g = np.asarray(self.scene.sim.gravity_vec, float)
        self.obst = Obstacles(self.scene, self.scene_dir)
        self.obst.set_facets(X, T)  # Spheres: the vertices' stand-off that keeps the triangles out
        # free rigid bodies (simcli.rigid): moving obstacles whose pose the rigid world integrates
        self.world = None
        if getattr(self.scene, "rigid_bodies", None):
            from simcli.rigid.world import world_for

            self.world = world_for(self.scene, self.scene_dir)
        # Dirichlet steps: prescribed motion (moving pins, moving colliders) is part of each Newton step
        self.dirichlet = self.moving_pins or self.obst.moving
        self.tau = 0.0  # the time moving colliders are at (lags self.time only while a contact blocks them)
        self._tau_to = None
        self._Hc = None
        # Mesh colliders: their triangles join the cloth's collision mesh as prescribed obstacle vertices
        # n .. n + nm - 1 (mesh_obstacles.py); ipctk's static-obstacle filter drops collider-collider pairs
        from simcli.solvers.fem.cloth.mesh_obstacles import MeshObstacles

        self.mobst = MeshObstacles(self.scene, self.scene_dir, self.world, self.dhat)
        self._body_loads = None  # the rigid bodies' loads, read by simcli.rigid.world (collider_poses)
        self.solid = None  # an FEM solid's boundary, prescribed per substep (solid_obstacles.py)
        if getattr(self, "_solid_fem", None) is not None:
            from simcli.solvers.fem.cloth.solid_obstacles import SolidSurface

            self.solid = SolidSurface(self._solid_fem)
            mu_s = max((e.material.friction for e in self.entities), default=0.0)
            self.solid.lo, self.solid.hi = self.mobst.append_surface(self.solid.V0, self.solid.T, mu_s)
            self.dirichlet = True
        self.rdofs = None  # the bodies' 6 unknowns each in the Newton system (rigid_dofs.py)
        if self.world is not None:
            from simcli.solvers.fem.cloth.rigid_dofs import RigidDofs

            self._body_loads = BodyLoads(self.world.n_colliders + len(self.world.bodies))
            self.rdofs = RigidDofs(self.world, self.mobst, len(X))
        self.nm = self.mobst.m
        self.vobs = self.mobst.positions(0.0)  # the obstacle vertices' current positions
        self.vobs_n = self.vobs
        self._po = None  # their displacement still to make in the pending Dirichlet step
        self._mesh_cross = None
        self._loads: dict[str, np.ndarray] = {}
        if self.nm:
            Xf = np.concatenate([X, self.mobst.V0])
            Tf = np.concatenate([T, self.mobst.T + self.n])
            self.cm = ipctk.CollisionMesh(Xf, ipctk.edges(Tf), Tf)
            self.cm.can_collide = ipctk.make_static_obstacle_filter(self.n)
            # friction coefficient per vertex for ipctk's blend (mesh_obstacles.blend_mu)
            self._mu_v = np.concatenate([np.full(self.n, self.mu_self), -(1.0 + self.mobst.vertex_mu)])
            # the narrow phase of the CCD: additive CCD (Li et al. 2021, conservative rescaling 0.9) where
            # Mesh colliders take part. Tight Inclusion (ipctk's default, kept for scenes without them)
            # spends ~100 us per point-triangle query of a cloth vertex resting a few mm over a collider
            # face 100 times its size (tolerance 1e-6 of the face's parameter domain); additive CCD 0.5 us
            # (a cloth on a triangulated box: CCD 8.4 s against 0.09 s in 25 substeps, same trajectory)
            self._accd = ipctk.AdditiveCCD()
        else:
            self.cm = ipctk.CollisionMesh(X, ipctk.edges(T), T)
        self.mesh_mu = float(max(self.mobst.friction, default=0.0))
        self._named_convex = any(self.scene.colliders[ci].name is not None for ci in self.obst.index)
        self.B = ipctk.BarrierPotential(self.dhat, 1.0)  # unit stiffness: kappa multiplies it
        self.bbox = float(np.linalg.norm(np.ptp(X, axis=0))) or 1.0
        self.kappa = None
        self.free_dofs = np.nonzero(np.repeat(~self.fixed, 3))[0]
        self.fixed_dofs = np.nonzero(np.repeat(self.fixed, 3))[0]
        self._dof_map = np.full(3 * self.n, -1, dtype=np.int64)
        self._dof_map[self.free_dofs] = np.arange(len(self.free_dofs))
        # ipctk's matrices also have the obstacle vertices' dofs (3 n ..): never unknowns
        self._ipc_map = np.concatenate([self._dof_map, np.full(3 * self.nm, -1, dtype=np.int64)])
        self._dof_ii = np.arange(3 * self.n)
        blk = np.arange(self.n)[:, None, None] * 3
        self._blk_ii = np.broadcast_to(blk + np.arange(3)[None, :, None], (self.n, 3, 3)).ravel()
        self._blk_jj = np.broadcast_to(blk + np.arange(3)[None, None, :], (self.n, 3, 3)).ravel()
        self._cand = None
        self._lu = None
        self._pat = None  # the Newton matrix's sparsity (see _fixed_pattern_sum)
        self._built = True

    def _full(self, x, vo=None):
        """Positions of the ipctk collision mesh: the cloth's, then the Mesh colliders' (current ones unless
        vo is given)."""
        if not self.nm:
            return x
        return np.concatenate([x, self.vobs if vo is None else vo])

    def _build_pins(self, xs, offs):
        """Prescribed motion of the fixed vertices (material.fixed_velocity or fixed_motion, per region):
        pin_idx (the moving ones), their rest positions and one simcli.motion.Motion each region."""
        from simcli.geometry.regions import points_in_shape
        from simcli.motion import Motion

        idx, mot = [], []
        motions = []
        for k, e in enumerate(self.entities):
            mat = e.material
            fm = list(mat.fixed_motion or [])
            if mat.fixed_velocity is not None:
                fm = [None]  # one translation for every region
            if not fm or not e.fixed_regions:
                continue
            x = xs[k]
            taken = np.zeros(len(x), bool)
            for j, r in enumerate(e.fixed_regions):
                held = points_in_shape(r, x) & ~taken
                taken |= held
                if not held.any():
                    continue
                spec = fm[j] if len(fm) > 1 else fm[0]
                if spec is None:
                    v, w, piv = np.asarray(mat.fixed_velocity, float), np.zeros(3), np.zeros(3)
                else:
                    v, w = np.asarray(spec.linear_velocity, float), np.asarray(spec.angular_velocity, float)
                    piv = x[held].mean(axis=0) if spec.pivot is None else np.asarray(spec.pivot, float)
                if not (np.any(v) or np.any(w)):
                    continue
                motions.append(Motion(3, piv, None, None, None, v=v, w=w))
                ii = np.nonzero(held)[0] + offs[k]
                idx.append(ii)
                mot.append(np.full(len(ii), len(motions) - 1))
        self.moving_pins = bool(idx)
        self.pin_idx = np.concatenate(idx) if idx else np.zeros(0, np.int64)
        self.pin_motion = np.concatenate(mot) if mot else np.zeros(0, np.int64)
        self.pin_motions = motions
        self.pin_rest = self.X[self.pin_idx].copy() if idx else np.zeros((0, 3))

    def _pin_target(self, t: float) -> np.ndarray:
        """Prescribed positions of the moving pinned vertices at time t."""
        out = np.empty_like(self.pin_rest)
        for j, m in enumerate(self.pin_motions):
            sel = self.pin_motion == j
            out[sel] = m.pose(t).to_world(self.pin_rest[sel])
        return out

    def _pin_velocity(self, t: float) -> np.ndarray:
        out = np.empty_like(self.pin_rest)
        for j, m in enumerate(self.pin_motions):
            sel = self.pin_motion == j
            P = m.pose(t)
            out[sel] = P.velocity_at(P.to_world(self.pin_rest[sel]))
        return out

    def _edge_loads(self, xs, ts, offs):
        """Dead loads [N] per vertex from each entity's boundary_conditions tractions: on every free edge
        (one triangle only) with both ends in the region, traction x |e| x thickness, half to each end."""
        from simcli.geometry.regions import points_in_shape

        f = np.zeros((offs[-1], 3))
        for k, e in enumerate(self.entities):
            if not e.material.boundary_conditions:
                continue
            x, t = xs[k], ts[k] - offs[k]
            he = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
            key = np.sort(he, axis=1)
            uniq, cnt = np.unique(key, axis=0, return_counts=True)
            free_edges = uniq[cnt == 1]
            for bc in e.material.boundary_conditions:
                inside = points_in_shape(bc.region, x)
                sel = free_edges[inside[free_edges].all(axis=1)]
                if len(sel) == 0:
                    self.warnings.append(f"{e.name}: traction region holds no free edge")
                    continue
                le = np.linalg.norm(x[sel[:, 1]] - x[sel[:, 0]], axis=1)
                fe = (0.5 * le * e.material.thickness)[:, None] * np.asarray(bc.traction, float)[None, :]
                dest = f
                if bc.ramp_time > 0:  # kept apart: scaled by min(1, t / ramp_time) each step
                    dest = np.zeros_like(f)
                    self._load_ramps.append((dest, float(bc.ramp_time)))
                for a in range(2):
                    np.add.at(dest[offs[k] : offs[k + 1]], sel[:, a], fe)
        return f

    def _loads_at(self, t: float) -> np.ndarray:
        """The dead loads at time t (ramped tractions grow linearly to their value at ramp_time)."""
        f = self.fext_full
        for fr, tr in self._load_ramps:
            f = f + min(1.0, t / tr) * fr
        return f

    # --------------------------------------------------------- the potential
    def _obstacle_terms(self, x, order, fr, tau=None):
        """Barrier (and friction from the lagged data fr) of vertices against obstacles (moving ones at time
        tau). With a Dirichlet step pending (self._tau_to), also the Newton system's coupling to the moving
        obstacles' remaining motion: self._obst_cross = sum over active pairs of H_pair u (u: the obstacle's
        surface displacement at the vertex from tau to _tau_to)."""
        sh = self.dhat**2
        if order >= 2:
            self._obst_cross = None
        d, nrm, _ = self.obst.distances(x, tau)
        act = d < self.dhat
        e = 0.0
        g = np.zeros_like(x) if order >= 1 else None
        Hd = np.zeros((self.n, 3, 3)) if order >= 2 else None
        n_act = int(act.sum())
        if n_act:
            k, i = np.nonzero(act)
            dd = np.maximum(d[k, i], 1e-300)
            b, b1, b2 = _barrier(dd**2, sh)
            nn = nrm[k, i]
            e += self.kappa * float(b.sum())
            if order >= 1:
                np.add.at(g, i, (self.kappa * b1 * 2 * dd)[:, None] * nn)
            if order >= 2:
                c = np.maximum(self.kappa * (4 * dd**2 * b2 + 2 * b1), 0.0)
                np.add.at(Hd, i, c[:, None, None] * nn[:, :, None] * nn[:, None, :])
                if self._tau_to is not None and self.obst.moving:
                    u = self.obst.surface_displacement(x, tau, self._tau_to)[k, i]
                    self._obst_cross = np.zeros_like(x)
                    np.add.at(self._obst_cross, i, (c * np.einsum("ij,ij->i", nn, u))[:, None] * nn)
        if fr is not None:
            i, lam, nn, mu, uo = fr
            u = x[i] - self.xn[i] - uo  # relative to the obstacle's surface
            uT = u - np.einsum("ij,ij->i", u, nn)[:, None] * nn
            y = np.linalg.norm(uT, axis=1)
            eps = EPS_V * self.dt
            f0 = np.where(y < eps, -(y**3) / (3 * eps**2) + y**2 / eps + eps / 3, y)
            f1y = np.where(y < eps, 2 / eps - y / eps**2, 1 / np.maximum(y, 1e-300))
            e += float(np.sum(mu * lam * f0))
            if order >= 1:
                np.add.at(g, i, (mu * lam * f1y)[:, None] * uT)
            if order >= 2:  # exact Hessian of mu lam f0(|u_T|) (positive semi-definite: see docs/FEM.md)
                T = np.eye(3) - nn[:, :, None] * nn[:, None, :]
                uu = uT[:, :, None] * uT[:, None, :]
                yy = np.maximum(y, 1e-12 * eps)
                c2 = np.where(y < eps, -1.0 / (eps**2 * yy), -1.0 / yy**3)
                np.add.at(
                    Hd, i, (mu * lam)[:, None, None] * (f1y[:, None, None] * T + c2[:, None, None] * uu)
                )
        return e, g, Hd, n_act

    def _potential(self, x, order=2, tau=None):
        import ipctk
        import scipy.sparse as sp

        dt = self.dt
        M = self.mass[:, None]
        dx = x - self.xhat
        e = 0.5 * float(np.sum(M * dx * dx)) / dt**2
        step = x - self.xn
        e += 0.5 * float(np.sum((self.damp * self.mass)[:, None] * step * step)) / dt
        if self.fext_any:  # dead loads: potential -f . x
            e -= float(np.sum(self.fext * x))
        ee, ge, He = self.model.energy_grad_hess(x, order, self._inertia)
        e += ee
        eo, go, Hd, n_obst = self._obstacle_terms(x, order, self._fric, tau)
        e += eo
        g = None
        if order >= 1:  # order 0: the energy alone (line-search trials)
            g = M * dx / dt**2
            g = g + (self.damp * self.mass)[:, None] * step / dt
            if self.fext_any:
                g = g - self.fext
            g = g + ge
            g = g + go
        n = self.n
        xf = self._full(x)  # with the Mesh colliders' vertices (rows past n: prescribed, dropped)
        col = ipctk.NormalCollisions()
        if self._cand is not None:  # the broad phase of this Newton step's swept segment (see substep)
            col.build(self._cand, self.cm, xf, self.dhat)
        else:
            col.build(self.cm, xf, self.dhat)
        n_self = len(col)
        Hs = None
        rd = self.rdofs
        g_obs = np.zeros((self.nm, 3)) if rd is not None and order >= 1 else None
        if n_self:
            e += self.kappa * self.B(col, self.cm, xf)
            if order >= 1:
                gB = self.kappa * self.B.gradient(col, self.cm, xf).reshape(-1, 3)
                g = g + gB[:n]
                if g_obs is not None:
                    g_obs += gB[n:]
            if order >= 2:
                Hs = self.kappa * self.B.hessian(col, self.cm, xf, ipctk.PSDProjectionMethod.CLAMP)
        Hf = None
        if self._tc is not None:  # lagged self-contact friction: dt D((x - x_n) / dt) (ipctk)
            V = (xf - self.xnf) / dt
            e += dt * self.FP(self._tc, self.cm, V)
            if order >= 1:
                gF = self.FP.gradient(self._tc, self.cm, V).reshape(-1, 3)
                g = g + gF[:n]
                if g_obs is not None:
                    g_obs += gF[n:]
            if order >= 2:
                Hf = self.FP.hessian(self._tc, self.cm, V, ipctk.PSDProjectionMethod.CLAMP) / dt
        if rd is not None:  # the rigid bodies' inertia, and the contact's gradient in their unknowns
            e += rd.energy()
            if order >= 1:
                self._gb = rd.gradient(g_obs)
        if order < 2:
            return e, g, None, n_self + n_obst
        t0 = time.perf_counter()
        rows, cols, vals = He
        diag = np.repeat(self.mass / dt**2 + self.damp * self.mass / dt, 3)
        # the elastic, inertia and obstacle blocks (and the bending model's edge unknowns): a pattern that
        # stays put from one Newton step to the next, summed through a cached map (_fixed_pattern_sum);
        # the self-contact blocks (few, their pattern changing) are added to that as a sparse matrix
        parts_r, parts_c = [rows, self._dof_ii, self._blk_ii], [cols, self._dof_ii, self._blk_jj]
        parts_v = [vals, diag, Hd.ravel()]
        var_r, var_c, var_v = [], [], []
        for Hx in (Hs, Hf):
            if Hx is not None:
                Hc = Hx.tocoo()
                var_r.append(Hc.row)
                var_c.append(Hc.col)
                var_v.append(Hc.data)
        nf = len(self.free_dofs)
        if self.dirichlet:  # the free rows' coupling to prescribed dofs: H_fc (for H_fc p_c in the rhs)
            ra, ca = np.concatenate(parts_r + var_r), np.concatenate(parts_c + var_c)
            va = np.concatenate(parts_v + var_v)
            r, c = self._ipc_map[ra], self._ipc_map[ca]
            kc = (r >= 0) & (c < 0) & (ca < 3 * self.n)
            self._Hc = (r[kc], ca[kc], va[kc])
            self._mesh_cross = None
            if self._po is not None:  # H_fo p_o: the moving Mesh colliders' remaining motion
                ko = (r >= 0) & (ca >= 3 * self.n)
                w = va[ko] * self._po.ravel()[ca[ko] - 3 * self.n]
                self._mesh_cross = np.bincount(r[ko], weights=w, minlength=nf)
        aux = self.model.aux
        n_aux = 0
        if aux is not None:  # the bending model's edge unknowns, eliminated by this solve (shape_operator.py)
            C, A2 = aux
            n_aux = C.shape[0]
            Cc = C.tocoo()
            A2c = A2.tocoo()
            # rows of the edge unknowns after the free dofs; a negative (fixed) column is dropped below
            er = Cc.row.astype(np.int64) + 3 * self.n
            parts_r += [er, Cc.col, A2c.row.astype(np.int64) + 3 * self.n]
            parts_c += [Cc.col, er, A2c.col.astype(np.int64) + 3 * self.n]
            parts_v += [Cc.data, Cc.data, A2c.data]
            if self.dirichlet:
                self._aux_c = C[:, self.fixed_dofs]
        H = self._fixed_pattern_sum(parts_r, parts_c, parts_v, nf + n_aux)
        if rd is not None:
            H = self._with_bodies(H, [Hx for Hx in (Hs, Hf) if Hx is not None])
        elif var_r:
            r = self._ipc_map[np.concatenate(var_r)]
            c = self._ipc_map[np.concatenate(var_c)]
            v = np.concatenate(var_v)
            keep = (r >= 0) & (c >= 0)
            H = H + sp.csc_matrix((v[keep], (r[keep], c[keep])), shape=H.shape)
        self.stats["assemble_s"] += time.perf_counter() - t0
        return e, g, H, n_self + n_obst

    def _with_bodies(self, H, contact):
        """H (free dofs and edge unknowns, N) grown by the rigid bodies' 6 unknowns each: P^T H_c P of the
        contact Hessians (ipctk numbering: cloth vertices, then obstacle vertices), P the free cloth dofs'
        identity and the bodies' dy/dq (rigid_dofs.py), plus their inertia blocks; held body dofs decoupled
        (identity rows)."""
        import scipy.sparse as sp

        rd = self.rdofs
        N = H.shape[0]
        nb6 = 6 * rd.nb
        fd = self.free_dofs
        Pc = sp.csr_matrix((np.ones(len(fd)), (fd, np.arange(len(fd)))), shape=(3 * self.n, N + nb6))
        Jb = rd.jacobian(self.nm)
        Pb = sp.hstack([sp.csr_matrix((3 * self.nm, N)), Jb]).tocsr()
        P = sp.vstack([Pc, Pb]).tocsr()
        out = sp.bmat([[H, None], [None, sp.csc_matrix(rd.inertia_blocks())]], format="csc")
        for Hx in contact:
            out = out + (P.T @ Hx @ P).tocsc()
        held = rd.fixed_mask()
        self._held_cols = None
        if held.any():
            # the free rows' coupling to the held dofs (for H_fh p_h in the rhs of a Dirichlet step)
            self._held_cols = out[:, N + np.flatnonzero(held)].tocsr()
            keep = np.concatenate([np.ones(N), (~held).astype(float)])
            D = sp.diags(keep)
            out = (D @ out @ D + sp.diags(1.0 - keep)).tocsc()
        return out

    def _fixed_pattern_sum(self, parts_r, parts_c, parts_v, N):
        """CSC (N, N) of the free dofs (and, past 3n, the bending model's edge unknowns) summed from COO
        parts in the global numbering (entries of fixed dofs dropped). The sorting of (row, col) pairs that
        a COO -> CSC conversion does at every Newton step is done once: it is kept (self._pat) with the
        rows and columns it was made for and reused while they are the same (as they are for every Newton
        step but the few where the bending Hessian's sparsity changes)."""
        import scipy.sparse as sp

        R = np.concatenate(parts_r)
        C = np.concatenate(parts_c)
        V = np.concatenate(parts_v)
        pat = self._pat
        if (
            pat is None
            or pat[0].shape != R.shape
            or not (np.array_equal(pat[0], R) and np.array_equal(pat[1], C))
        ):
            m = np.concatenate(
                [self._dof_map, np.arange(R.max(initial=0) + 1 - 3 * self.n) + len(self.free_dofs)]
            )
            r, c = m[R], m[C]
            keep = (r >= 0) & (c >= 0)
            lin = c[keep] * N + r[keep]
            uniq, inv = np.unique(lin, return_inverse=True)
            slot = np.full(len(R), len(uniq), np.int64)  # dropped entries go to a spare slot
            slot[keep] = inv.ravel()
            indptr = np.concatenate([[0], np.cumsum(np.bincount(uniq // N, minlength=N))]).astype(np.int32)
            self._pat = pat = (R.copy(), C.copy(), slot, (uniq % N).astype(np.int32), indptr)
        data = np.bincount(pat[2], weights=V, minlength=len(pat[3]) + 1)[: len(pat[3])]
        return sp.csc_matrix((data, pat[3], pat[4]), shape=(N, N))

    def _lagged_friction(self, x, tau=None, tau_end=None):
        if self.kappa is None:
            return None
        d, nrm, mu = self.obst.distances(x, tau)
        act = (d < self.dhat) & (mu[:, None] > 0)
        if not act.any():
            return None
        k, i = np.nonzero(act)
        dd = np.maximum(d[k, i], 1e-300)
        _, b1, _ = _barrier(dd**2, self.dhat**2)
        lam = -self.kappa * b1 * 2 * dd  # normal force magnitude [N]
        uo = np.zeros((len(i), 3))
        if self.obst.moving and tau_end is not None:  # the surface's own motion over the step
            uo = self.obst.surface_displacement(x, tau, tau_end)[k, i]
        self._fric_k = k  # which obstacle each lagged pair is against (collider loads)
        return i, lam, nrm[k, i], mu[k], uo

    def _linear_solve(self, H, rhs):
        """Newton direction from H p = rhs (H: free dofs, CSC, SPD by construction).

        A sparse direct factorisation (solvers.fem.linear_solver: CHOLMOD's supernodal Cholesky through
        cvxopt, or SuperLU in symmetric mode, minimum-degree ordering on A^T + A, no pivoting: the projected
        Hessian is SPD), kept through the substep: later Newton steps first run CG
        preconditioned by the previous factor (the Hessian changes little between Newton steps), to
        min(REUSE_CG_RTOL, 100 pcg_tol) within REUSE_CG_ITERS iterations (an inexact Newton step), and
        refactor when that fails. Jacobi-PCG is the fallback
        if the factorisation fails (it should not: H is SPD)."""
        import scipy.sparse.linalg as spl

        if self._lu is not None:
            M = spl.LinearOperator(H.shape, matvec=self._lu.solve, dtype=np.float64)
            it = [0]

            def count(_):
                it[0] += 1

            pf, info = spl.cg(
                H,
                rhs,
                M=M,
                rtol=min(self.REUSE_CG_RTOL, 100.0 * self.opts.pcg_tol),
                maxiter=self.REUSE_CG_ITERS,
                callback=count,
            )
            self.stats["pcg_reuse_iterations"] += it[0]
            if info == 0 and np.all(np.isfinite(pf)) and pf @ rhs > 0:
                return pf
        try:
            if self._cholmod:
                self._lu = CholmodFactor(H, self._blas_limit)
            else:
                self._lu = spl.splu(
                    H,
                    permc_spec="MMD_AT_PLUS_A",
                    diag_pivot_thresh=0.0,
                    options={"SymmetricMode": True},
                )
            self.stats["factorizations"] += 1
            pf = self._lu.solve(rhs)
            if np.all(np.isfinite(pf)) and pf @ rhs > 0:
                return pf
        except (RuntimeError, ArithmeticError):  # singular or not positive definite (should not happen: SPD)
            pass
        self._lu = None
        Hr = H.tocsr()
        dg = np.maximum(Hr.diagonal(), 1e-300)
        pre = spl.LinearOperator(Hr.shape, matvec=lambda r: r / dg)
        pf, info = spl.cg(Hr, rhs, M=pre, rtol=self.opts.pcg_tol, maxiter=self.opts.pcg_max_iter)
        if info != 0:
            self.stats["pcg_capped"] += 1
        if not np.all(np.isfinite(pf)) or pf @ rhs <= 0:
            pf = rhs / dg
        return pf

    def _step_limit(self, x, p, tau=None, tau_to=None):
        """Largest alpha in (0, 1] free of intersections: CCD against itself and obstacles (moving ones going
        from their pose at tau to that at tau_to over the step)."""
        import ipctk

        t0 = time.perf_counter()
        a = min(1.0, self.obst.first_contact(x, p, t0=tau, t1=tau_to))
        # one broad phase per Newton step: the segment x -> x + a p, boxes inflated by contact_distance,
        # serves the CCD below, every line-search trial on it and the next Newton step's collision set
        # (all their points lie on the segment; pairs within dhat have overlapping inflated boxes)
        x0 = self._full(x)
        x1 = self._full(x + a * p, None if self._po is None else self.vobs + a * self._po)
        self._cand = ipctk.Candidates()
        self._cand.build(self.cm, x0, x1, self.dhat)
        if a > 0:
            if self.nm:  # Mesh colliders: additive CCD (see build)
                a1 = self._cand.compute_collision_free_stepsize(self.cm, x0, x1, 0.0, self._accd)
            else:
                a1 = self._cand.compute_collision_free_stepsize(self.cm, x0, x1)
            a = min(a, float(a1) * a)
        self.stats["ccd_s"] += time.perf_counter() - t0
        return a

    def _straight_free(self, x0, x1, v0, v1) -> bool:
        """Whether the straight path from (x0, v0) to (x1, v1) (cloth vertices, obstacle vertices) is free of
        intersections. A rigid body's trial state is its exact rotation exp(a dtheta) R, on an arc, not on the
        chord _step_limit checked (at 0.6 rad a step the two differ by millimetres): the line search checks
        the path to the positions it accepts, so every accepted state is intersection-free."""
        import ipctk

        t0 = time.perf_counter()
        X0, X1 = self._full(x0, v0), self._full(x1, v1)
        cand = ipctk.Candidates()
        cand.build(self.cm, X0, X1, self.dhat)
        a = float(cand.compute_collision_free_stepsize(self.cm, X0, X1, 0.0, self._accd))
        self.stats["ccd_s"] += time.perf_counter() - t0
        return a >= 1.0

    def _expand(self, x, p, gp: float, e: float, e1: float, tau=None, tau_to=None):
        """The line search's expansion phase (EXPAND_RATIO): (alpha, x + alpha p, Phi there), from the
        accepted full step (1, x + p, e1) of a Newton step p with directional derivative gp = g.p < 0 at x,
        where Phi(x) = e. Every trial lies within the CCD's bound for the longest step (whose broad phase
        also becomes the next Newton step's candidate set: the segment covers the accepted point)."""
        best = (1.0, x + p, e1)
        if not gp < 0:
            return best
        ratio = (e1 - e) / (0.5 * gp)
        if not ratio > self.EXPAND_RATIO:
            return best
        amax = self.EXPAND_MAX
        if ratio < 2.0 - 2.0 / amax:  # positive curvature: up to twice the quadratic's minimum
            amax = 2.0 / (2.0 - ratio)
        lim = amax * self._step_limit(x, amax * p, tau, tau_to)
        self.stats["expansions"] += 1
        at = 1.0
        while at < lim:
            at = min(2.0 * at, lim)
            xt = x + at * p
            et = self._potential(xt, 0, tau)[0]
            if _DEBUG:
                print("    expand ratio %.4f limit %.2f alpha %.2f dE %.3e" % (ratio, lim, at, et - e))
            if not et < best[2]:
                break
            best = (at, xt, et)
        return best

    def substep(self, dt: float) -> None:
        import ipctk

        self.dt = dt
        # each vertex's inertia in the Newton matrix, shared among its triangles (model.membrane: the
        # projection of compressed triangles keeps their negative curvature as far as this covers it)
        self._inertia = self.mass * (1.0 / dt**2 + self.damp / dt) / self._valence
        self.xn = self.x.copy()
        free = ~self.fixed
        self.xhat = self.xn + dt * self.v + dt * dt * self.g
        self.xhat[self.fixed] = self.xn[self.fixed]
        t_end = self.time + dt
        if self._load_ramps:  # backward Euler: the loads at the step's end
            self.fext = self._loads_at(t_end)
        tau = self.tau if self.obst.moving else None  # moving colliders' time at the iterate
        pin_to = None
        if self.moving_pins:  # Dirichlet: the pinned vertices' prescribed positions at the step's end
            pin_to = self._pin_target(t_end)
            self.xhat[self.pin_idx] = pin_to
        if self.kappa is None:
            # barrier stiffness: the barrier's force at half contact_distance holds ten times the heaviest
            # vertex's weight (at least 1 m/s^2 of acceleration), -kappa b'(d^2) 2 d = 10 m g; doubled later
            # whenever a gap closes below 1 % of contact_distance (IPC's adaptive update, Li et al. 2020)
            d = 0.5 * self.dhat
            _, b1, _ = _barrier(np.array([d * d]), self.dhat**2)
            load = 10.0 * float(self.mass.max()) * max(float(np.linalg.norm(self.g)), 1.0)
            self.kappa = load / (-float(b1[0]) * 2 * d)
            self.kappa_max = 1e8 * self.kappa
        self._fric = None
        self._fric = self._lagged_friction(self.xn, tau, t_end if tau is not None else None)
        self._tc = None
        sol_to = None
        if self.solid is not None:  # the FEM solid's surface: to its positions at the substep's end
            sol_to = self.solid.target(t_end, dt)
        rd = self.rdofs
        if rd is not None:  # the bodies' unknowns, from where the last solve left them (rigid_dofs.py)
            rd.start(dt, self.g)
            rd.write(self.vobs)
        self.vobs_n = self.vobs.copy() if self.nm else self.vobs
        self.xnf = self._full(self.xn, self.vobs_n)
        if self.mu_self > 0 or self.mesh_mu > 0:  # ipctk's friction (self, Mesh colliders) lagged at x_n
            col = ipctk.NormalCollisions()
            col.build(self.cm, self.xnf, self.dhat)
            if len(col):
                self._tc = ipctk.TangentialCollisions()
                Bk = ipctk.BarrierPotential(self.dhat, self.kappa)
                if self.nm:
                    from simcli.solvers.fem.cloth.mesh_obstacles import blend_mu

                    self._tc.build(self.cm, self.xnf, col, Bk, self._mu_v, self._mu_v, blend_mu)
                else:
                    self._tc.build(self.cm, self.xn, col, Bk, self.mu_self)
                self.FP = ipctk.FrictionPotential(EPS_V)
        x = self.xn.copy()
        fd = self.free_dofs
        self._cand = None  # broad phase and factor live within one substep (checkpoints stay exact)
        self._lu = None
        res0 = None
        it = 0
        ncontact = 0
        for it in range(1, self.opts.newton_max_iter + 1):
            # prescribed motion still to make in this step: pinned vertices' and moving colliders'
            pc = pin_to - x[self.pin_idx] if pin_to is not None else None
            pending = pc is not None and bool(np.any(pc))
            dtau, tau_to = 0.0, tau
            if tau is not None and tau < t_end:
                # to t_end, or to the next keyframe before it: the colliders' motion over one Newton step
                # stays one straight piece, as the CCD takes it
                tau_to = self.obst.next_key(tau, t_end)
                dtau = tau_to - tau
                pending = True
            self._tau_to = tau_to if dtau > 0 else None
            self._po = None
            vo_to = None
            if (
                dtau > 0 and self.mobst.moving
            ):  # the Mesh colliders' vertices: straight to their pose at tau_to
                vo_to = self.mobst.positions(tau_to)
                self._po = vo_to - self.vobs
                if rd is not None:  # the bodies are unknowns, not prescribed
                    for lo, hi in rd.ranges:
                        self._po[lo:hi] = 0.0
                        vo_to[lo:hi] = self.vobs[lo:hi]
            d_sol = None
            if sol_to is not None:  # the solid surface's motion still to make (a Dirichlet step)
                sl = slice(self.solid.lo, self.solid.hi)
                d_sol = sol_to - self.vobs[sl]
                if self._po is not None:  # (prescribed colliders' step: mobst.positions has it at rest)
                    self._po[sl] = d_sol
                    vo_to[sl] = sol_to
                if np.any(d_sol):
                    pending = True
                    if self._po is None:
                        self._po = np.zeros((self.nm, 3))
                        self._po[sl] = d_sol
                        if dtau > 0:  # (a moving convex collider alone: the chord's end, for a = 1)
                            vo_to = self.vobs.copy()
                            vo_to[sl] = sol_to
                else:
                    d_sol = None
            dq_held = None
            if rd is not None:  # held body dofs: their prescribed motion still to make (a Dirichlet step)
                dq_held = rd.held_offset()
                if np.any(dq_held):
                    pending = True
                else:
                    dq_held = None
            e, g, H, ncontact = self._potential(x, 2, tau)
            r = g[free] / self.mass[free, None]
            res = float(np.abs(r).max()) if r.size else 0.0
            if res0 is None:  # (the cloth's: a body's first residual is its inertia's, v / dt in free flight)
                res0 = res
            if rd is not None:
                gb = np.where(rd.fixed_mask(), 0.0, self._gb)
                res = max(res, rd.residual(gb))
            if _DEBUG:
                print("  it", it, "res %.3e" % res, "e %.6e" % e, "nc", ncontact, "pending", pending)
            if not pending and (res <= self.opts.newton_atol or res <= self.opts.newton_tol * res0):
                it -= 1
                break
            t0 = time.perf_counter()
            rhs = -g.ravel()[fd]
            p = np.zeros((self.n, 3))
            if pending:
                # Dirichlet step: H_ff p_f = -g_f - H_fc p_c (+ the moving obstacles' coupling)
                if pc is not None:
                    p[self.pin_idx] = pc
                    ri, cj, hv = self._Hc
                    rhs = rhs - np.bincount(ri, weights=hv * p.ravel()[cj], minlength=len(fd))
                if dtau > 0 and self._obst_cross is not None:
                    rhs = rhs + self._obst_cross.ravel()[fd]
                if self._po is not None and self._mesh_cross is not None:
                    rhs = rhs - self._mesh_cross
            nb6 = 6 * rd.nb if rd is not None else 0
            n_aux = H.shape[0] - len(fd) - nb6
            if n_aux:  # edge unknowns of the bending model: at their optimum, so no residual of their own
                r_aux = np.zeros(n_aux)
                if pending and pc is not None:
                    r_aux = -(self._aux_c @ p.ravel()[self.fixed_dofs])
                rhs = np.concatenate([rhs, r_aux])
            if nb6:
                rhs = np.concatenate([rhs, -gb])
                if dq_held is not None and self._held_cols is not None:
                    hi_ = np.flatnonzero(rd.fixed_mask())
                    rhs = rhs - self._held_cols @ dq_held[hi_]
                    rhs[len(rhs) - nb6 + hi_] = dq_held[hi_]
            sol = self._linear_solve(H, rhs)
            pf = sol[: len(fd)]
            pb = sol[len(sol) - nb6 :] if nb6 else None
            self.stats["solve_s"] += time.perf_counter() - t0
            p.ravel()[fd] = pf
            pmax = float(np.abs(pf).max(initial=0.0))
            if pb is not None:  # the bodies' step: the translation, and the rotation times the body's reach
                pmax = max(pmax, rd.step_size(pb))
            if not pending and pmax <= max(self.opts.newton_atol * dt, self.opts.newton_vtol) * dt:
                # converged: the Newton step's acceleration |p| / dt^2 is below newton_atol, or its
                # velocity |p| / dt below newton_vtol (docs/FEM.md, Newton's stopping tests)
                break
            if pb is not None:  # the bodies' vertices: on the chord to their pose at a = 1 (the CCD's path)
                if self._po is None:
                    self._po = np.zeros((self.nm, 3))
                    vo_to = None
                u1, R1, _ = rd.trial(1.0, pb)
                for (lo, hi), y1, y0 in zip(rd.ranges, rd.positions(u1, R1), rd.positions()):
                    self._po[lo:hi] = y1 - y0
                    if vo_to is not None:
                        vo_to[lo:hi] = y1
            a = a0 = self._step_limit(x, p, tau, tau_to)
            if pending and a0 < self.STALL_ALPHA:
                self._lu = None  # (see STALL_ALPHA) the next Newton direction from a fresh factor
            ok = False
            if pending:
                # the prescribed motion raises the energy as it may: the step goes as far as the continuous
                # collision check lets it (every state stays intersection-free); the next Newton steps
                # minimise over the free vertices again. A rotating collider's true pose within the step
                # is not the straight body-frame path the CCD took: the trial state is checked exactly
                for _ in range(40):
                    xt = x + a * p
                    if a <= 0:
                        break
                    if dtau == 0 or float(self.obst.distances(xt, tau + a * dtau)[0].min()) > 0:
                        if pb is None:
                            ok = True
                            break
                        vt = self.vobs + a * self._po  # the bodies at their exact trial pose
                        rd.write(vt, *rd.trial(a, pb)[:2])
                        if self._straight_free(x, xt, self.vobs, vt):
                            ok = True
                            break
                    a *= 0.5
            else:
                keep_b = (rd.u, rd.R, rd.th, self.vobs.copy()) if pb is not None else None
                for _ in range(40):
                    xt = x + a * p
                    if pb is not None:  # the bodies' trial pose (exact rigid map), from the step's start
                        rd.accept(keep_b[:3])
                        rd.accept(rd.trial(a, pb))
                        rd.write(self.vobs)
                        if not self._straight_free(x, xt, keep_b[3], self.vobs):
                            a *= 0.5
                            continue
                    et = self._potential(xt, 0, tau)[0]
                    if et <= e:
                        ok = True
                        break
                    a *= 0.5
                if not ok and keep_b is not None:
                    rd.accept(keep_b[:3])
                    self.vobs = keep_b[3]
                if ok and a == 1.0 and pb is None:  # the full step at the first trial: expand it?
                    a, xt, et = self._expand(x, p, float(np.dot(g.ravel()[fd], pf)), e, et, tau, tau_to)
            if not ok:
                self.stats["line_search_fail"] += 1
                break
            if pending and pb is not None:
                rd.accept(rd.trial(a, pb))
            x = xt
            if d_sol is not None:
                vs0 = self.vobs[sl].copy()
            if dtau > 0:
                tau = tau_to if a >= 1.0 else tau + a * dtau
                if self._po is not None:  # on the chord the CCD checked (exactly the pose at a = 1)
                    if a >= 1.0 and vo_to is not None:
                        self.vobs = vo_to
                    else:
                        self.vobs = self.vobs + min(a, 1.0) * self._po
            if d_sol is not None:  # on the chord (exactly the target at a = 1)
                self.vobs[sl] = sol_to if a >= 1.0 else vs0 + a * d_sol
            if pb is not None:
                rd.write(self.vobs)
            if _DEBUG:
                print("    alpha %.3e ccd %.3e |p| %.3e" % (a, a0, float(np.abs(p).max())))
            moved = a * pmax if pb is not None else float(np.abs(a * p).max())
            if not pending and moved < 1e-12 * self.bbox:
                break
        self._tau_to = None
        self._po = None
        self._cand = None
        self._lu = None
        if rd is not None:
            rd.finish()
        if self.solid is not None:
            self._solid_reaction(x, dt)
            # how far the cloth held the solid's surface back from the FEM solver's (the stagger's gap)
            lag = float(np.abs(sol_to - self.vobs[self.solid.lo : self.solid.hi]).max(initial=0.0))
            self.stats["solid_lag_max"] = max(self.stats.get("solid_lag_max", 0.0), lag)
        if self.nm and any(nm is not None for nm in self.mobst.names):
            self._add_mesh_loads(x, tau, dt)
        if self._named_convex:
            self._add_obstacle_loads(x, tau, dt)
        self.v = (x - self.xn) / dt
        self.x = x
        self.time += dt
        s = self.stats
        if pin_to is not None:  # prescribed positions a contact kept the pins from (caught up later)
            s["pin_lag_max"] = max(s.get("pin_lag_max", 0.0), float(np.abs(pin_to - x[self.pin_idx]).max()))
        if tau is not None:
            self.tau = tau
            s["collider_lag_max"] = max(s.get("collider_lag_max", 0.0), self.time - tau)
        s["substeps"] += 1
        s["newton_iterations"] += it
        s["max_newton"] = max(s["max_newton"], it)
        s["contacts"] += ncontact
        s["max_contacts"] = max(s["max_contacts"], ncontact)
        # IPC's barrier stiffness update (Li et al. 2020, supplement): a contact closing below 1 % of dhat
        # doubles kappa (up to kappa_max), so gaps stay a resolvable fraction of contact_distance
        if ncontact:
            dmin = float(self.obst.distances(x, tau)[0].min())
            col = ipctk.NormalCollisions()
            xf = self._full(x)
            col.build(self.cm, xf, self.dhat)
            if len(col):
                dmin = min(dmin, math.sqrt(max(col.compute_minimum_distance(self.cm, xf), 0.0)))
            s["min_distance"] = min(s.get("min_distance", math.inf), dmin)
            if dmin < 0.01 * self.dhat and self.kappa < self.kappa_max:
                self.kappa = min(2.0 * self.kappa, self.kappa_max)

    def _add_mesh_loads(self, x, tau, dt):
        """The contact's reaction on the Mesh colliders over this substep: minus the barrier's and friction's
        gradient on their vertices at the step's end state (what the cloth received, reversed), summed into
        self._loads as impulse and moment about each collider's pivot."""
        import ipctk

        xf = self._full(x)
        f = np.zeros((self.nm, 3))
        col = ipctk.NormalCollisions()
        col.build(self.cm, xf, self.dhat)
        if len(col):
            f -= self.kappa * self.B.gradient(col, self.cm, xf).reshape(-1, 3)[self.n :]
        if self._tc is not None:
            f -= self.FP.gradient(self._tc, self.cm, (xf - self.xnf) / dt).reshape(-1, 3)[self.n :]
        for name, a in self.mobst.loads(f, self.vobs, tau, dt).items():
            if name not in self.mobst.body_rows:
                self._loads[name] = self._loads.get(name, 0.0) + a
        rd = self.rdofs
        if rd is not None:  # a rigid body: the world reads it (and clears it) after this substep
            for k, (lo, hi) in enumerate(rd.ranges):
                c = rd.c_n[k] + rd.u[k]  # its centre of mass where the solve left it
                fk = f[lo:hi]
                row = self.mobst.body_rows[rd.bodies[k].name]
                self._body_loads.a[row, :3] += dt * fk.sum(axis=0)
                self._body_loads.a[row, 3:] += dt * np.cross(self.vobs[lo:hi] - c, fk).sum(axis=0)

    def _solid_reaction(self, x, dt):
        """The contact's reaction on the FEM solid's surface vertices over this substep (minus the barrier's
        and friction's gradient there at the end state), added to the solid's velocities (solid_obstacles)."""
        import ipctk

        xf = self._full(x)
        lo, hi = self.n + self.solid.lo, self.n + self.solid.hi
        f = np.zeros((hi - lo, 3))
        col = ipctk.NormalCollisions()
        col.build(self.cm, xf, self.dhat)
        if len(col):
            f -= self.kappa * self.B.gradient(col, self.cm, xf).reshape(-1, 3)[lo:hi]
        if self._tc is not None:
            f -= self.FP.gradient(self._tc, self.cm, (xf - self.xnf) / dt).reshape(-1, 3)[lo:hi]
        if np.any(f):
            self.solid.apply(f, dt)

    def _add_obstacle_loads(self, x, tau, dt):
        """The reaction on the named convex colliders over this substep: minus the barrier's and lagged
        friction's forces on the cloth's vertices at the step's end state, summed per collider as impulse and
        moment (at the surface point x - d n) about its pivot (moving: its pivot at tau)."""
        from simcli.motion import collider_centre

        d, nrm, _ = self.obst.distances(x, tau)
        n_conv = len(self.obst.specs)
        force = np.zeros((n_conv, self.n, 3))  # on the collider, per vertex
        act = d[6:] < self.dhat
        if act.any():
            k, i = np.nonzero(act)
            dd = np.maximum(d[6 + k, i], 1e-300)
            _, b1, _ = _barrier(dd**2, self.dhat**2)
            np.add.at(force, (k, i), (self.kappa * b1 * 2 * dd)[:, None] * nrm[6 + k, i])  # -(force on cloth)
        fr = self._fric
        if fr is not None:
            i, lam, nn, mu, uo = fr
            kk = self._fric_k - 6
            sel = kk >= 0
            u = x[i] - self.xn[i] - uo
            uT = u - np.einsum("ij,ij->i", u, nn)[:, None] * nn
            y = np.linalg.norm(uT, axis=1)
            eps = EPS_V * dt
            f1y = np.where(y < eps, 2 / eps - y / eps**2, 1 / np.maximum(y, 1e-300))
            np.add.at(force, (kk[sel], i[sel]), ((mu * lam * f1y)[:, None] * uT)[sel])
        for j, ci in enumerate(self.obst.index):
            name = self.scene.colliders[ci].name
            if name is None:
                continue
            P = self.obst._pose(6 + j, tau)
            piv = collider_centre(self.scene.colliders[ci], 3) if P is None else np.asarray(P.c, float)
            f = force[j]
            surf = x - d[6 + j][:, None] * nrm[6 + j]
            a = np.concatenate([dt * f.sum(axis=0), dt * np.cross(surf - piv, f).sum(axis=0)])
            self._loads[name] = self._loads.get(name, 0.0) + a

    def collider_loads(self) -> dict[str, np.ndarray]:
        """Named collider -> impulse [N s] and moment about its pivot [N m s] the cloth gave it since the last
        call (the IPC barrier's and friction's reaction; Mesh colliders and the convex ones alike)."""
        out, self._loads = getattr(self, "_loads", {}), {}
        return out

    def attach_solid(self, fem) -> None:
        """The FEM solver of the scene's tetrahedral entities (simcli.coupling.make_coupler calls this before
        the solvers are built): their boundary meets the cloth staggered (solid_obstacles.py)."""
        self._solid_fem = fem

    def collider_poses(self):
        """Where simcli.rigid.world reads the impulse the cloth gave each rigid body (None: no bodies)."""
        return self._body_loads if self._built else None

    # ------------------------------------------------------------ interface
    def sync(self) -> None:
        return None

    def frame_check(self) -> dict[str, FrameStats]:
        out = {}
        for k, e in enumerate(self.entities):
            lo, hi = self.offsets[k], self.offsets[k + 1]
            ok = np.isfinite(self.x[lo:hi]).all(axis=1) & np.isfinite(self.v[lo:hi]).all(axis=1)
            nbad = int((~ok).sum())
            sp = float(np.linalg.norm(self.v[lo:hi], axis=1).max()) if hi > lo else 0.0
            out[e.name] = FrameStats(finite=nbad == 0, max_speed=sp if nbad == 0 else math.inf, n_bad=nbad)
        return out

    def stable_dt(self, horizon: float = 0.0) -> float:
        return math.inf

    def runaway_cfl(self) -> float:
        """The runaway guard's limit in edges per substep: the base limit, or twice what the fastest
        prescribed motion (a moving collider's surface, moving pins) crosses in a substep when that is more
        (a sheet carried by it moves as fast, without blowing up: the step is implicit, the contact exact)."""
        from simcli.motion import sample_times

        base = super().runaway_cfl()
        if not getattr(self, "dirichlet", False) or not getattr(self, "dt", None):
            return base
        if getattr(self, "_vmax", None) is None:
            t_end = self.scene.sim.n_steps * self.scene.sim.dt
            reach = float(np.linalg.norm(self.obst.hi - self.obst.lo))  # any point of the domain
            v = 0.0
            for m in [*self.obst.motions, *self.obst.mesh_motions, *self.pin_motions]:
                if m is None:
                    continue
                for t in sample_times(m, t_end):
                    P = m.pose(float(t))
                    v = max(v, float(np.linalg.norm(P.v)) + float(np.linalg.norm(P.w)) * reach)
            self._vmax = v
        return max(base, 2.0 * self._vmax * self.dt / self.length_scale())

    def length_scale(self) -> float:
        e = self.tris
        return float(np.linalg.norm(self.X[e[:, 1]] - self.X[e[:, 0]], axis=1).mean())

    def entity_kind(self, name: str) -> str:
        return "triangles"

    def entity_cells(self, name: str):
        return self.cells[name]

    def entity_size(self, name: str) -> int:
        k = self.index[name]
        return self.offsets[k + 1] - self.offsets[k]

    def owns(self, name: str) -> bool:
        return name in getattr(self, "index", {e.name: 0 for e in self.entities})

    def default_fields(self, name: str) -> list[str]:
        return ["position", "velocity", "displacement"]

    def output_fields(self) -> dict[str, tuple[int, str]]:
        return {
            "position": (3, "m"),
            "velocity": (3, "m/s"),
            "displacement": (3, "m"),
            "mass": (1, "kg"),  # lumped vertex mass (rho thickness area / 3 of each triangle)
            "strain": (1, "-"),  # largest principal Green membrane strain, per triangle
            "stress": (1, "Pa"),  # von Mises of the membrane's second Piola-Kirchhoff stress, per triangle
        }

    def entity_arrays(self, name: str, fields: list[str]) -> dict[str, np.ndarray]:
        k = self.index[name]
        lo, hi = self.offsets[k], self.offsets[k + 1]
        out = {}
        for f in fields:
            if f == "position":
                a = self.x
            elif f == "velocity":
                a = self.v
            elif f == "displacement":
                a = self.x - self.X
            elif f == "mass":
                a = self.mass
            elif f in self.cell_fields:
                t0, t1 = self.tri_offsets[k], self.tri_offsets[k + 1]
                if f == "strain":
                    out[f] = np.linalg.eigvalsh(self.model.green_strain(self.x)[t0:t1])[:, -1]
                else:
                    S = self.model.stress(self.x)[t0:t1]
                    sxx, syy, sxy = S[:, 0, 0], S[:, 1, 1], S[:, 0, 1]
                    out[f] = np.sqrt(sxx**2 - sxx * syy + syy**2 + 3 * sxy**2)
                continue
            else:
                raise KeyError(
                    f"unknown FEM.Cloth output field {f!r}; known: position, velocity, displacement, mass"
                )
            out[f] = np.array(a[lo:hi])
        return out

    def get_state(self) -> dict[str, np.ndarray]:
        # kappa: IPC's adaptive barrier stiffness is state too (doubled when a gap closes below dhat / 100);
        # a resumed run must continue with it to equal the uninterrupted one bit for bit
        st = {"x": self.x.copy(), "v": self.v.copy(), "time": np.array([self.time])}
        if self.kappa is not None:
            st["kappa"] = np.array([self.kappa, self.kappa_max])
        if self.obst.moving:  # moving colliders' time (behind self.time while a contact held them back)
            st["tau"] = np.array([self.tau])
        if self.nm and (self.mobst.moving or self.solid is not None):  # (on a chord while held back)
            st["vobs"] = self.vobs.copy()
        if self.rdofs is not None and self.rdofs.end is not None:  # where the last solve left the bodies
            st["rigid_end"] = np.array([np.concatenate([c, R.ravel()]) for c, R in self.rdofs.end])
        return st

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        class _F:
            def __init__(self, owner, attr):
                self.o, self.a = owner, attr

            def from_numpy(self, arr):
                setattr(self.o, self.a, np.array(arr, dtype=np.float64))

        for key in ("x", "v"):
            upload_state_array(_F(self, key), state, key, (self.n, 3), np.float64, "FEM.Cloth")
        self.time = float(np.asarray(state.get("time", [0.0])).reshape(-1)[0])
        self.tau = float(np.asarray(state.get("tau", [self.time])).reshape(-1)[0])
        if self.nm:
            if "vobs" in state:
                self.vobs = np.array(state["vobs"], dtype=np.float64).reshape(self.nm, 3)
            else:
                self.vobs = self.mobst.positions(self.tau if self.mobst.moving else None)
        if self.rdofs is not None and "rigid_end" in state:
            a = np.asarray(state["rigid_end"], dtype=np.float64).reshape(-1, 12)
            self.rdofs.end = [(r[:3].copy(), r[3:].reshape(3, 3).copy()) for r in a]
        if "kappa" in state:  # absent in checkpoints written before it was saved: set at the next substep
            k = np.asarray(state["kappa"], dtype=np.float64).reshape(-1)
            self.kappa, self.kappa_max = float(k[0]), float(k[1])

    def counts(self) -> dict[str, int]:
        return {"vertices": self.n, "triangles": len(self.tris)}

    def info(self) -> dict[str, Any]:
        s = dict(self.stats)
        n = max(s["substeps"], 1)
        s["newton_per_substep"] = s["newton_iterations"] / n
        s["contacts_per_substep"] = s["contacts"] / n
        return {
            "method": "backward Euler, Newton + sparse direct factor (reused as CG preconditioner), IPC "
            "barrier (ipctk) + CCD line search (backtracking, or expanding a full step while the energy "
            "falls steeply)",
            "factorization": "CHOLMOD supernodal Cholesky (cvxopt)" if self._cholmod else "SuperLU (scipy)",
            "bending": "shape operator (both curvature invariants)"
            if self.model.shape is not None
            else "quadratic (flat rest)"
            if self.model.quadratic is not None
            else "discrete-shell hinges",
            "contact_distance": self.dhat,
            "barrier_stiffness": self.kappa,
            **s,
        }
