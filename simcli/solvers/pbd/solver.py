"""PBD solver: extended position-based dynamics (XPBD; Macklin, Mueller and Chentanez 2016) for cloth
and rods.

A substep reads like the paper (Algorithm 1)::

    predict -> reset multipliers -> project constraints (stretch sweeps, bending sweeps)
            -> particle contact (contact.py) -> walls and colliders (friction) -> update velocities

* Each constraint j keeps a Lagrange multiplier lambda_j, zeroed at the start of every substep and
  accumulated over the iterations: dlambda = (-C - alpha~ lambda) / (sum_i w_i |grad_i C|^2 + alpha~),
  alpha~ = compliance / dt^2 (eq. 18). The converged state is the implicit-Euler step of the elastic
  energy C^2 / (2 compliance), whatever the iteration count or substep; too few iterations only leave
  it unconverged (softer), never change the stiffness the solver aims for.
* Gauss-Seidel by graph colouring (topology.colour): no two constraints of one colour share a vertex,
  so a colour is one parallel loop without atomics and the colours follow each other inside one
  kernel (one Taichi task per colour). Gauss-Seidel propagates a correction through a chain in one
  sweep where Jacobi with averaging needs many.
* Contact (position level, after the constraints): a vertex closer than its radius (half
  particle_size for cloth, the rod radius for rods) to a wall or collider is pushed out along the
  surface normal; Coulomb friction acts on its tangential displacement over the substep (static:
  removed if below mu x penetration, kinetic: shortened by mu x penetration; Macklin et al. 2014,
  "Unified particle physics", sec. 6.1). Sticky walls and colliders remove it entirely.
* Velocities are the positions' change over the substep (v = (x - x_prev) / dt, computed as the
  predicted velocity plus correction / dt so that f32 round-off of the positions does not bias
  gravity); pinned vertices (``fixed``) have inverse mass 0.

Emitters and sinks (PBD.Liquid, PBD.Particle; simcli/solvers/sources.py): the meshed bodies (cloth, rods,
soft bodies) first, then the free-particle entities, then each emitter's reserved slots; every particle
loop, the contact and fluid hash grids run over the active count, and a sink removes free particles only
(compaction from the first free slot: constraint indices never move). Scenes without emitters or sinks
take the original path (a constant particle count, one fluid pass per PBD.Liquid entity).
"""

import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.scene.output_fields import FIELDS
from simcli.solvers.base import Body, FrameStats, Solver, frame_stats_per_body, upload_state_array
from simcli.solvers.pbd.topology import PBDMesh, colour, fixed_vertices, mesh_for_entity
from simcli.solvers.sources import ActiveSet, has_sources, is_emitter
from simcli.solvers.taichi_funcs import make_body_frame_stats, make_finite

with stdout_to_stderr():
    import taichi as ti

OUTPUT_FIELDS = FIELDS["PBD"]  # the Taichi-free table validate checks (simcli/scene/output_fields.py)
# Up to this many constraints the sweeps of a substep run in one single-threaded kernel launch: a launch
# and a task per colour cost ~10-60 us on a CPU, a constraint ~20 ns.
SERIAL_CONSTRAINTS = 4000
LIQUID_BODY = 1 << 20  # contact body ids of liquid particles (liquid-liquid pairs are the fluid's business)


# emitted layers that keep the nozzle's prescribed motion: ceil(h / particle_size) + 1 with h = 2 particle
# sizes (PBF's smoothing length; PBD.Particle's contact reach is one)
BUFFER_LAYERS = 3
LIQUID_BODY_GAP = 0.5  # PBD.Liquid vs a rigid body: contact distance / particle radius (see contact())


class _ConstraintSet:
    """Constraints of one kind (k vertices each), ordered by colour: indices, rest values,
    compliances and multipliers as fields, colour offsets as a compile-time tuple."""

    def __init__(
        self,
        name: str,
        arity: int,
        idx: np.ndarray,
        rest: np.ndarray,
        compliance: np.ndarray,
        n_vertices: int,
    ):
        self.name, self.arity = name, arity
        order, offsets = colour(idx, n_vertices)
        self.idx = idx[order]
        self.rest = rest[order]
        self.compliance = compliance[order]
        self.offsets = tuple(int(o) for o in offsets)
        self.k = int(idx.shape[0])

    @property
    def colours(self) -> int:
        return len(self.offsets) - 1

    def allocate(self, f, npf):
        k = max(self.k, 1)
        self.f_idx = ti.Vector.field(self.arity, ti.i32, shape=k)
        self.f_rest = ti.field(f, shape=k)
        self.f_comp = ti.field(f, shape=k)
        self.f_lam = ti.field(f, shape=k)
        if self.k:
            self.f_idx.from_numpy(self.idx.astype(np.int32))
            self.f_rest.from_numpy(self.rest.astype(npf))
            self.f_comp.from_numpy(self.compliance.astype(npf))


class PBDSolver(Solver):
    family = "pbd"

    def __init__(self, scene: Any, bodies: list[Body], scene_dir=None) -> None:
        super().__init__(scene, bodies)
        self.dim = D = int(scene.sim.dim)
        self.opts = scene.solvers.pbd
        self.entities = [e for e in scene.entities if e.family == "PBD"]
        if D == 2:  # free particles only (config.check_2d refuses the rest first, with its location)
            from simcli.solvers.pbd.config import check_2d

            for e in self.entities:
                for _, msg in check_2d(e, scene):
                    raise ValueError(f"entity '{e.name}': {msg}")
        elif D != 3:
            raise ValueError("PBD entities need sim.dim 2 or 3")
        self.scene_dir = scene_dir  # collider motion files are relative to it
        self.meshes = [mesh_for_entity(e, scene_dir, self.opts, D) for e in self.entities]
        # emitters and sinks (simcli/solvers/sources.py): an active count; None in scenes without them
        self.sources = None
        if has_sources(scene, "PBD"):
            self._source_layout(scene, bodies)
        self._index = {e.name: k for k, e in enumerate(self.entities)}
        self.offsets = [0]
        for m in self.meshes:
            self.offsets.append(self.offsets[-1] + m.n)
        self.n = self.offsets[-1]
        if self.sources is not None:
            self.sources = ActiveSet(
                scene, [SimpleNamespace(n=m.n, entity=e) for e, m in self._pairs()], "PBD"
            )
        self.active_set = self.sources
        self._prepare_host()
        self._built = False
        self.time = 0.0
        self.last_dt = 0.0

    def _pairs(self):
        return list(zip(self.entities, self.meshes))

    def _source_layout(self, scene, bodies) -> None:
        """Active mode: meshed bodies first (sinks never move them), free particles next, then one block of
        ``max_particles + 1`` slots per emitter (the last a fresh row, simcli/solvers/sources.py), each
        emitted particle carrying rho x particle_size^dim (the lattice cell, as a sampled block's; per
        metre of depth in 2D)."""
        pairs = sorted(zip(self.entities, self.meshes), key=lambda em: not em[1].meshed)  # stable
        self.entities = [e for e, _ in pairs]
        self.meshes = [m for _, m in pairs]
        self.n_meshed = sum(m.n for m in self.meshes if m.meshed)
        ps = float(self.opts.particle_size)
        for b in bodies:
            if not is_emitter(b):
                continue
            n = b.n
            self.entities.append(b.entity)
            self.meshes.append(
                PBDMesh(
                    x=np.asarray(b.x, dtype=np.float64),
                    mass=np.full(n, float(b.entity.material.rho) * ps**self.dim),
                    kind="particles",
                    cells=np.zeros((0, 1)),
                    stretch=np.zeros((0, 2), np.int64),
                    stretch_rest=np.zeros(0),
                    meshed=False,
                )
            )
        self.sources = True  # the ActiveSet follows, once the offsets exist

    # ---------------------------------------------------------------- host side
    def _prepare_host(self) -> None:
        n, D = self.n, self.dim
        x0 = np.zeros((n, D))
        xs = np.zeros((n, D))
        v = np.zeros((n, D))
        mass = np.zeros(n)
        fixed = np.zeros(n, bool)
        radius = np.zeros(n)
        drag = np.zeros(n)
        body = np.zeros(n, np.int32)
        mu_s = np.zeros(n)
        mu_k = np.zeros(n)
        st, st_r, st_c, bd, bd_r, bd_c, dh, dh_r, dh_c, tv, tv_r, tv_c = ([] for _ in range(12))
        meshed = np.zeros(n, np.int32)
        lid = np.full(n, -1, np.int32)  # active mode: the liquid (parameters) of each particle, -1 none
        vfix = np.zeros((n, D))
        self.warnings = []
        for k, (e, m) in enumerate(zip(self.entities, self.meshes)):
            lo, hi = self.offsets[k], self.offsets[k + 1]
            mat = e.material
            x0[lo:hi] = m.x
            xs[lo:hi] = m.x
            if getattr(mat, "initial_stretch", None) is not None:
                c = m.x.mean(axis=0)
                xs[lo:hi] = c + (m.x - c) * np.asarray(mat.initial_stretch, dtype=np.float64)
            if e.velocity is not None:
                v[lo:hi] = np.asarray(e.velocity, dtype=np.float64)
            mass[lo:hi] = m.mass
            held = fixed_vertices(e, m.x)
            if e.fixed_regions and not held.any():
                self.warnings.append(f"{e.name}: fixed region holds no vertex")
            fixed[lo:hi] = held
            if getattr(mat, "fixed_velocity", None) is not None:
                vfix[lo:hi][held] = np.asarray(mat.fixed_velocity, dtype=np.float64)
            radius[lo:hi] = m.radius if m.radius > 0 else 0.5 * self.opts.particle_size
            drag[lo:hi] = mat.air_resistance
            body[lo:hi] = k
            mu_s[lo:hi], mu_k[lo:hi] = mat.static_friction, mat.kinetic_friction
            st.append(m.stretch + lo)
            st_r.append(m.stretch_rest)
            st_c.append(np.full(len(m.stretch), getattr(mat, "stretch_compliance", 0.0)))
            meshed[lo:hi] = int(m.meshed)
            if mat.type == "PBD.Liquid":
                lid[lo:hi] = int(lid.max()) + 1
            if getattr(mat, "bending_compliance", None) is None:  # a chain, particles: no bending constraints
                m.bend_dist, m.dihedral = m.bend_dist[:0], m.dihedral[:0]
                m.bend_dist_rest, m.dihedral_rest = m.bend_dist_rest[:0], m.dihedral_rest[:0]
            bd.append(m.bend_dist + lo)
            bd_r.append(m.bend_dist_rest)
            bd_c.append(np.full(len(m.bend_dist), getattr(mat, "bending_compliance", None) or 0.0))
            dh.append(m.dihedral + lo)
            dh_r.append(m.dihedral_rest)
            dh_c.append(np.full(len(m.dihedral), getattr(mat, "bending_compliance", None) or 0.0))
            tv.append(m.tets + lo)
            tv_r.append(m.tets_rest)
            tv_c.append(np.full(len(m.tets), getattr(mat, "volume_compliance", 0.0)))
        v[fixed] = vfix[fixed]
        self.vfix = vfix
        self.x0, self.xstart, self.v0, self.mass, self.fixed = x0, xs, v, mass, fixed
        self.radius, self.drag, self.body, self.mu_s, self.mu_k = radius, drag, body, mu_s, mu_k
        self.meshed = meshed
        self.lid_host = lid
        self.inv_mass = np.where(fixed, 0.0, 1.0 / np.maximum(mass, 1e-300))
        cat = np.concatenate
        self.stretch = _ConstraintSet(
            "stretch", 2, cat(st).astype(np.int64).reshape(-1, 2), cat(st_r), cat(st_c), n
        )
        self.bend_dist = _ConstraintSet(
            "bend_dist", 2, cat(bd).astype(np.int64).reshape(-1, 2), cat(bd_r), cat(bd_c), n
        )
        self.dihedral = _ConstraintSet(
            "dihedral", 4, cat(dh).astype(np.int64).reshape(-1, 4), cat(dh_r), cat(dh_c), n
        )
        self.volume = _ConstraintSet(
            "volume", 4, cat(tv).astype(np.int64).reshape(-1, 4), cat(tv_r), cat(tv_c), n
        )
        self.edge = float(np.mean(self.stretch.rest)) if self.stretch.k else self.opts.particle_size
        # small bodies: every sweep of a substep in one single-threaded launch (see project_serial); free
        # particles only (no constraints): nothing to project
        n_cons = self.stretch.k + self.bend_dist.k + self.dihedral.k + self.volume.k
        self.serial = 0 < n_cons <= SERIAL_CONSTRAINTS

    # --------------------------------------------------------------------- build
    def build(self) -> None:
        if self._built:
            return
        from simcli.colliders import ColliderPoses, collider_motions, collider_specs, wall_specs

        f = ti.f64 if self.scene.sim.precision == "f64" else ti.f32
        self.f = f
        npf = self.npf = np.float64 if f == ti.f64 else np.float32
        n, D = self.n, self.dim
        V3 = lambda k: ti.Vector.field(D, f, shape=k)  # (D components: 3, or 2 in a 2D scene)
        self.x, self.v, self.xp, self.x0_f, self.reaction = V3(n), V3(n), V3(n), V3(n), V3(n)
        self.w = ti.field(f, shape=n)
        self.vfix_f = V3(n)
        self.vfix_f.from_numpy(self.vfix.astype(npf))
        self.rad = ti.field(f, shape=n)
        self.drag_f = ti.field(f, shape=n)
        self.gravity = ti.Vector.field(D, f, shape=())
        self.x.from_numpy(self.xstart.astype(npf))
        self.v.from_numpy(self.v0.astype(npf))
        self.x0_f.from_numpy(self.x0.astype(npf))
        self.w.from_numpy(self.inv_mass.astype(npf))
        self.rad.from_numpy(self.radius.astype(npf))
        self.drag_f.from_numpy(self.drag.astype(npf))
        self.gravity[None] = [float(c) for c in self.scene.sim.gravity_vec[:D]]
        self.count = self._count_func()
        if self.sources is not None:  # per-particle identity, mass and liquid (active mode)
            self.pid = ti.field(ti.i32, shape=n)
            self.pid.from_numpy(np.arange(n, dtype=np.int32))
            self.mass_f = ti.field(f, shape=n)
            self.mass_f.from_numpy(self.mass.astype(npf))
            self.lid = ti.field(ti.i32, shape=n)
            self.lid.from_numpy(self.lid_host)
        for cs in (self.stretch, self.bend_dist, self.dihedral, self.volume):
            cs.allocate(f, npf)
        # walls and colliders: kinds compile-time, numbers in fields
        self.walls = wall_specs(self.scene, D)
        self.cols = collider_specs(self.scene, D, self.scene_dir)
        # moving and named colliders: pose per substep, loads (compiled only when a collider needs them)
        self.poses = ColliderPoses(self.cols, collider_motions(self.scene, D, self.scene_dir), D, f)
        self.poses.allocate()
        from simcli.collider_mesh_kernels import PBDRestitution, mesh_fields

        self.mesh_fields = mesh_fields(self.cols, f)  # Mesh colliders' signed-distance grids
        self.restitution = PBDRestitution(  # compiled only when a collider has restitution
            self.cols, n, f, self.v, float(np.linalg.norm(self.scene.sim.gravity_vec)), D
        )
        nc = max(1, len(self.cols))
        self.col_a, self.col_b = V3(nc), V3(nc)
        self.col_r, self.col_hh, self.col_mu = (ti.field(f, shape=nc) for _ in range(3))
        for k, c in enumerate(self.cols):
            self.col_a[k], self.col_b[k] = c.a, c.b
            self.col_r[k], self.col_hh[k], self.col_mu[k] = c.radius, c.half_height, c.friction
        lo, hi = self.scene.domain.bounds(D)
        self.dom_lo, self.dom_hi = V3(()), V3(())
        self.dom_lo[None], self.dom_hi[None] = lo, hi
        self.wall_mu = ti.field(f, shape=2 * D)
        self.wall_mu.from_numpy(np.array([w.friction for w in self.walls], npf))
        nb = len(self.entities)
        self.body_off = ti.field(ti.i32, shape=nb + 1)
        self.body_off.from_numpy(np.array(self.offsets, np.int32))
        self.stat_speed = ti.field(f, shape=nb)
        self.stat_bad = ti.field(ti.i32, shape=nb)
        self.contact = None
        if self.opts.collisions:
            from simcli.solvers.pbd.contact import ParticleContact

            body_f = ti.field(ti.i32, shape=n)
            liquid = np.zeros(n, bool)
            for k, e in enumerate(self.entities):
                liquid[self.offsets[k] : self.offsets[k + 1]] = e.material.type == "PBD.Liquid"
            ids = np.where(self.meshed > 0, self.body, -1 - np.arange(n))
            # active mode: the liquids are one fluid (their pairs the fluid's business, not contact's)
            ids = np.where(liquid, LIQUID_BODY + (0 if self.sources is not None else self.body), ids)
            body_f.from_numpy(ids.astype(np.int32))
            self.body_f = body_f
            mus, muk = ti.field(f, shape=n), ti.field(f, shape=n)
            self.mus, self.muk = mus, muk
            mus.from_numpy(self.mu_s.astype(npf))
            muk.from_numpy(self.mu_k.astype(npf))
            self.contact = ParticleContact(
                n,
                f,
                4.0 * float(self.radius.max()),
                self.x,
                self.xp,
                self.x0_f,
                self.w,
                self.rad,
                body_f,
                mus,
                muk,
                None if self.sources is None else self.count,
            )
        self.liquids = []
        if self.sources is not None:
            self._active_liquid()
        for k, e in enumerate(self.entities if self.sources is None else []):
            if e.material.type == "PBD.Liquid":
                from simcli.solvers.pbd.liquid import PBFLiquid

                lo, hi = self.offsets[k], self.offsets[k + 1]
                self.liquids.append(
                    PBFLiquid(
                        self,
                        lo,
                        hi,
                        self.opts.particle_size,
                        float(self.mass[lo]),
                        self.opts,
                        (
                            e.material.density_relaxation,
                            e.material.viscosity_relaxation,
                            e.material.vorticity_confinement,
                        ),
                        e.material.artificial_pressure,
                    )
                )
        if self.sources is not None:
            self._build_sources()
        self._make_kernels()
        self._built = True
        self.frame_check()

    # ------------------------------------------------------------ emitters and sinks
    def _count_func(self):
        """The particle loops' bound: the active count with emitters or sinks, else the constant n."""
        if self.sources is None:
            n = self.n

            @ti.func
            def count():
                return n

            return count
        src = self.sources

        @ti.func
        def count():  # (the count field exists by the time a kernel compiles: ActiveSet.build)
            return src.nact[None]

        return count

    def _liquid_params(self) -> list:
        """Active mode: the distinct liquids (entities and emitters), in order: the lid of each."""
        return [e.material for e in self.entities if e.material.type == "PBD.Liquid"]

    def _active_liquid(self) -> None:
        """Active mode: one position-based fluid pass over every active particle, liquids by lid."""
        mats = self._liquid_params()
        if not mats:
            return
        from simcli.solvers.pbd.liquid import PBFLiquid

        par = ti.Vector.field(4, self.f, shape=len(mats))
        par.from_numpy(
            np.array(
                [
                    [
                        m.density_relaxation,
                        m.artificial_pressure,
                        m.viscosity_relaxation,
                        m.vorticity_confinement,
                    ]
                    for m in mats
                ],
                dtype=self.npf,
            )
        )
        first = int(np.flatnonzero(self.lid_host >= 0)[0])
        self.liquids.append(
            PBFLiquid(
                self,
                0,
                self.n,
                self.opts.particle_size,
                float(self.mass[first]),
                self.opts,
                (
                    mats[0].density_relaxation,
                    max(m.viscosity_relaxation for m in mats),
                    max(m.vorticity_confinement for m in mats),
                ),
                mats[0].artificial_pressure,
                active=(self.count, self.mass_f, self.lid, par),
            )
        )

    def _build_sources(self) -> None:
        src = self.sources
        persistent = [self.x, self.v, self.x0_f, self.w, self.vfix_f, self.rad, self.drag_f]
        persistent += [self.pid, self.mass_f, self.lid]
        em_ents = [self.entities[e["body"]] for e in src.emitters]
        liq_idx = [k for k, e in enumerate(self.entities) if e.material.type == "PBD.Liquid"]
        lid_of = {k: i for i, k in enumerate(liq_idx)}
        masses = [float(self.mass[self.offsets[e["body"]]]) for e in src.emitters]
        for e, m in zip(src.emitters, masses):
            e["mass"] = m
        consts = {
            self.mass_f: masses,
            self.w: [1.0 / m for m in masses],
            self.lid: [lid_of.get(e["body"], -1) for e in src.emitters],
            self.drag_f: [e.material.air_resistance for e in em_ents],
        }
        if self.contact is not None:
            persistent += [self.body_f, self.mus, self.muk]
            consts[self.body_f] = [LIQUID_BODY if e.material.type == "PBD.Liquid" else -1 for e in em_ents]
            consts[self.mus] = [e.material.static_friction for e in em_ents]
            consts[self.muk] = [e.material.kinetic_friction for e in em_ents]
        for liq in self.liquids:
            persistent.append(liq.rho)
        # inflow buffer (as SPH's, simcli/solvers/sources.py): the layers within one smoothing length (2
        # particle sizes, also past PBD.Particle's contact reach) of the nozzle keep its prescribed motion,
        # a piston that feeds the jet at its speed and rest spacing. Without it the newest layer is placed
        # a spacing behind the previous one wherever that one has got to: a layer slowed by a push is
        # overlapped, and PBD resolves the overlap within a substep (dv = overlap / substep), which grows
        # into a burst (a 2D jet at particle_size 0.005 m, 1 m/s, was 3 m/s sideways within 0.1 s)
        src.build(
            self,
            persistent,
            consts,
            self.f,
            buffer_layers=BUFFER_LAYERS,
            first=self.n_meshed,
            mass=self.mass_f,
        )
        x, x0, pid, lid = self.x, self.x0_f, self.pid, self.lid
        has_body = self.contact is not None
        body = self.body_f if has_body else self.lid  # (lid: a placeholder, never written)

        @ti.kernel
        def entered(a: ti.i32, b: ti.i32):
            """Emitted particles [a, b): their rest position (displacement output) and, PBD.Particle, a
            contact id of their own (free particles collide with each other)."""
            for s in range(a, b):
                x0[s] = x[s]
                if ti.static(has_body):
                    if lid[s] < 0:
                        body[s] = -1 - pid[s]

        self._entered = entered
        self._n_seen = src.n_active
        entered(0, 0)  # compiled with the build
        for g in [liq.grid for liq in self.liquids] + (
            [self.contact.grid] if self.contact is not None else []
        ):
            g.resize(src.n_active)

    def active_changed(self) -> None:
        """The active count changed (emission, sinks): the new particles' ids, the grids' table sizes."""
        n = self.sources.n_active
        if n > self._n_seen:
            self._entered(self._n_seen, n)
        self._n_seen = n
        if self.contact is not None:
            self.contact.grid.resize(n)
        for liq in self.liquids:
            liq.grid.resize(n)

    def n_live(self) -> int:
        """Particles and vertices in the simulation now (the active count)."""
        return self.n if self.sources is None else self.sources.n_active

    def _make_kernels(self) -> None:
        n = self.n
        N = self.count  # the active count (emitters, sinks) or the constant n
        x, v, xp, w, rad, drag, gravity = self.x, self.v, self.xp, self.w, self.rad, self.drag_f, self.gravity
        vfix = self.vfix_f
        eps = 1e-12 if self.f == ti.f64 else 1e-9
        D = self.dim

        @ti.kernel
        def predict(dt: float):
            for i in range(N()):
                xp[i] = x[i]
                if w[i] > 0:
                    vi = (v[i] + dt * gravity[None]) * ti.exp(-drag[i] * dt)
                    v[i] = vi
                    x[i] = x[i] + dt * vi
                else:  # held: pinned, or moving on its prescribed path
                    x[i] = x[i] + dt * vfix[i]

        sets = (self.stretch, self.bend_dist, self.dihedral, self.volume)

        @ti.kernel
        def reset_multipliers():
            for cs in ti.static(sets):
                for k in range(cs.k):
                    cs.f_lam[k] = 0.0

        def distance_func(cs):
            idx, rest, comp, lam = cs.f_idx, cs.f_rest, cs.f_comp, cs.f_lam

            @ti.func
            def project(k, inv_dt2):
                i, j = idx[k][0], idx[k][1]
                wsum = w[i] + w[j]
                d = x[i] - x[j]
                length = d.norm()
                if wsum > 0 and length > eps:
                    nrm = d / length
                    at = comp[k] * inv_dt2
                    dl = (-(length - rest[k]) - at * lam[k]) / (wsum + at)
                    lam[k] += dl
                    x[i] += w[i] * dl * nrm
                    x[j] -= w[j] * dl * nrm

            return project

        def dihedral_func(cs):
            idx, rest, comp, lam = cs.f_idx, cs.f_rest, cs.f_comp, cs.f_lam

            @ti.func
            def project(k, inv_dt2):
                q = idx[k]
                x1, x2, x3, x4 = x[q[0]], x[q[1]], x[q[2]], x[q[3]]
                E = x4 - x3
                le = E.norm()
                n1 = (x1 - x3).cross(x1 - x4)
                n2 = (x2 - x4).cross(x2 - x3)
                s1, s2 = n1.norm_sqr(), n2.norm_sqr()
                wsum = w[q[0]] + w[q[1]] + w[q[2]] + w[q[3]]
                if wsum > 0 and le > eps and s1 > eps * eps and s2 > eps * eps:
                    a1, a2 = n1 / s1, n2 / s2
                    g1 = -le * a1
                    g2 = -le * a2
                    g3 = -((x1 - x4).dot(E) * a1 + (x2 - x4).dot(E) * a2) / le
                    g4 = ((x1 - x3).dot(E) * a1 + (x2 - x3).dot(E) * a2) / le
                    u1, u2 = n1 / ti.sqrt(s1), n2 / ti.sqrt(s2)
                    C = ti.atan2(u1.cross(u2).dot(E) / le, u1.dot(u2)) - rest[k]
                    if C > math.pi:  # the angle wraps at +-pi
                        C -= 2.0 * math.pi
                    elif C < -math.pi:
                        C += 2.0 * math.pi
                    den = (
                        w[q[0]] * g1.norm_sqr()
                        + w[q[1]] * g2.norm_sqr()
                        + w[q[2]] * g3.norm_sqr()
                        + w[q[3]] * g4.norm_sqr()
                    )
                    at = comp[k] * inv_dt2
                    if den + at > eps:
                        dl = (-C - at * lam[k]) / (den + at)
                        lam[k] += dl
                        x[q[0]] += w[q[0]] * dl * g1
                        x[q[1]] += w[q[1]] * dl * g2
                        x[q[2]] += w[q[2]] * dl * g3
                        x[q[3]] += w[q[3]] * dl * g4

            return project

        def volume_func(cs):
            """Tet volume C = V - V0, V = (x2 - x1) x (x3 - x1) . (x4 - x1) / 6 (Macklin et al. 2016
            sec. 5)."""
            idx, rest, comp, lam = cs.f_idx, cs.f_rest, cs.f_comp, cs.f_lam

            @ti.func
            def project(k, inv_dt2):
                q = idx[k]
                x1, x2, x3, x4 = x[q[0]], x[q[1]], x[q[2]], x[q[3]]
                g2 = (x3 - x1).cross(x4 - x1) / 6.0
                g3 = (x4 - x1).cross(x2 - x1) / 6.0
                g4 = (x2 - x1).cross(x3 - x1) / 6.0
                g1 = -(g2 + g3 + g4)
                C = (x2 - x1).dot(g2) - rest[k]
                den = (
                    w[q[0]] * g1.norm_sqr()
                    + w[q[1]] * g2.norm_sqr()
                    + w[q[2]] * g3.norm_sqr()
                    + w[q[3]] * g4.norm_sqr()
                )
                at = comp[k] * inv_dt2
                if den + at > eps * eps * eps:
                    dl = (-C - at * lam[k]) / (den + at)
                    lam[k] += dl
                    x[q[0]] += w[q[0]] * dl * g1
                    x[q[1]] += w[q[1]] * dl * g2
                    x[q[2]] += w[q[2]] * dl * g3
                    x[q[3]] += w[q[3]] * dl * g4

            return project

        def sweep_kernel(cs, project):
            """One Gauss-Seidel sweep: the colours one after another, each colour one parallel loop."""

            @ti.kernel
            def sweep(dt: float):
                inv_dt2 = 1.0 / (dt * dt)
                for c in ti.static(range(cs.colours)):
                    for k in range(cs.offsets[c], cs.offsets[c + 1]):
                        project(k, inv_dt2)

            return sweep

        st, bd, dh, tv = self.stretch, self.bend_dist, self.dihedral, self.volume
        p_st, p_bd, p_dh, p_tv = distance_func(st), distance_func(bd), dihedral_func(dh), volume_func(tv)
        self._solve_volume = sweep_kernel(tv, p_tv) if tv.k else None
        self._solve_stretch = sweep_kernel(st, p_st) if st.k else None
        self._solve_bend_dist = sweep_kernel(bd, p_bd) if bd.k else None
        self._solve_dihedral = sweep_kernel(dh, p_dh) if dh.k else None

        @ti.kernel
        def project_serial(dt: float, stretch_iters: int, bending_iters: int):
            """Every sweep of a substep in one launch, on one thread (small bodies, where launching a
            kernel per sweep and a task per colour costs more than the constraints; same order, same
            result as the parallel sweeps)."""
            inv_dt2 = 1.0 / (dt * dt)
            ti.loop_config(serialize=True)
            for _ in range(1):
                for it in range(stretch_iters):
                    for k in range(st.k):
                        p_st(k, inv_dt2)
                    for k in range(tv.k):  # volume with the stretch sweeps (soft bodies)
                        p_tv(k, inv_dt2)
                for it in range(bending_iters):
                    for k in range(bd.k):
                        p_bd(k, inv_dt2)
                    for k in range(dh.k):
                        p_dh(k, inv_dt2)

        self._project_serial = project_serial

        from simcli.colliders import sdf_box, sdf_cylinder, sdf_plane, sdf_sphere

        walls, cols, poses = self.walls, self.cols, self.poses
        mesh_f, rest = self.mesh_fields, self.restitution
        nc = len(cols)
        col_a, col_b, col_r, col_hh, col_mu = self.col_a, self.col_b, self.col_r, self.col_hh, self.col_mu
        dom_lo, dom_hi, wall_mu = self.dom_lo, self.dom_hi, self.wall_mu

        @ti.func
        def push(xi, xpi, phi, nrm, r, mu, sticky: ti.template(), friction: ti.template()):
            """Move xi out to distance r from a surface (signed distance phi, unit normal nrm), then
            Coulomb friction on the tangential displacement since the substep's start."""
            pen = r - phi
            xo = xi
            if pen > 0:
                xo = xi + pen * nrm
                d = xo - xpi
                dt_ = d - d.dot(nrm) * nrm
                lt = dt_.norm()
                if ti.static(not friction):
                    pass
                elif ti.static(sticky):
                    xo -= dt_
                elif lt > 0 and mu > 0:
                    if lt <= mu * pen:
                        xo -= dt_
                    else:
                        xo -= dt_ * (mu * pen / lt)
            return xo

        # PBD.Liquid against a free rigid body whose solid it counts in its density (liquid.py,
        # liquid_walls): the contact is only a guard at half the particle's radius, a quarter particle from
        # the surface; the wall density holds the liquid at its lattice distance. At the full radius (half a
        # particle) the clamp held PBF's compressed liquid off the body, which floated ~5% high
        # (docs/RIGID.md). Per-entity liquids only (with emitters, lid-indexed liquids keep the full radius).
        liq_ranges = (
            [(liq.lo, liq.hi) for liq in self.liquids]
            if self.sources is None
            and self.opts.liquid_walls
            and any(getattr(c, "rigid", False) for c in cols)
            else []
        )

        @ti.func
        def body_gap(i, r):
            out = r
            for q in ti.static(liq_ranges):
                if q[0] <= i and i < q[1]:
                    out = LIQUID_BODY_GAP * r
            return out

        @ti.kernel
        def contact(friction: ti.template()):
            for i in range(N()):
                if w[i] > 0:
                    xi, xpi, r = x[i], xp[i], rad[i]
                    for fc in ti.static(range(2 * D)):
                        ax = walls[fc].axis
                        nrm = ti.Vector.zero(float, D)
                        phi = 0.0
                        if ti.static(walls[fc].side < 0):
                            nrm[ax] = 1.0
                            phi = xi[ax] - dom_lo[None][ax]
                        else:
                            nrm[ax] = -1.0
                            phi = dom_hi[None][ax] - xi[ax]
                        xi = push(xi, xpi, phi, nrm, r, wall_mu[fc], walls[fc].contact == "sticky", friction)
                    for k in ti.static(range(nc)):
                        phi = 1.0
                        nrm = ti.Vector.zero(float, D)
                        xq = xi
                        if ti.static(cols[k].moving):  # the body-frame SDF at the substep's end pose
                            xq = poses.to_body(k, xi, 1)
                        if ti.static(cols[k].kind == "Plane"):
                            phi, nrm = sdf_plane(xq, col_a[k], col_b[k])
                        elif ti.static(cols[k].kind == "Sphere"):
                            phi, nrm = sdf_sphere(xq, col_a[k], col_r[k])
                        elif ti.static(cols[k].kind == "Box"):
                            phi, nrm = sdf_box(xq, col_a[k], col_b[k])
                        elif ti.static(cols[k].kind == "Cylinder" and D == 3):
                            phi, nrm = sdf_cylinder(xq, col_a[k], col_r[k], col_hh[k], cols[k].axis)
                        elif ti.static(cols[k].kind == "Mesh" and D == 3):
                            phi, nrm = mesh_f[k].sample(xq)
                        if ti.static(cols[k].moving):
                            nrm = poses.normal_to_world(k, nrm, 1)
                        if ti.static(friction and cols[k].restitution > 0):
                            vw = ti.Vector.zero(float, D)
                            if ti.static(cols[k].moving):
                                vw = poses.velocity(k, xi, 1)
                            rest.record(i, k, phi - r, nrm, v[i] - vw, vw)
                        if ti.static(cols[k].moving):
                            # friction on the displacement relative to the surface's own over the substep
                            xref = xpi + poses.velocity(k, xi, 1) * poses.dt[None]
                            rr = r
                            if ti.static(cols[k].rigid):
                                rr = body_gap(i, r)
                            xo = push(
                                xi, xref, phi, nrm, rr, col_mu[k], cols[k].contact == "sticky", friction
                            )
                            if ti.static(poses.named[k] and (friction or cols[k].rigid)):
                                # the momentum the contact gives the particle, -m (xo - xi) / dt,
                                # goes to the collider (a rigid body's: also the liquids' clamping passes,
                                # whose pushes are momentum the body gives the liquid too)
                                poses.add_load(k, xo, -(xo - xi) / (w[i] * poses.dt[None]), 1)
                            xi = xo
                        elif ti.static(poses.named[k]):
                            xo = push(xi, xpi, phi, nrm, r, col_mu[k], cols[k].contact == "sticky", friction)
                            if ti.static(friction):
                                poses.add_load(k, xo, -(xo - xi) / (w[i] * poses.dt[None]), 1)
                            xi = xo
                        else:
                            xi = push(xi, xpi, phi, nrm, r, col_mu[k], cols[k].contact == "sticky", friction)
                    x[i] = xi

        @ti.kernel
        def update_velocity(dt: float):
            """v = (x - x_prev) / dt, written as the predicted velocity plus the constraints' and contacts'
            correction over dt: in f32, x - x_prev is rounded to ulp(x) (1.2e-7 m at 1 m), which at a
            substep of 4e-4 s makes g dt^2 only ~13 ulps and would bias gravity by several per cent; the
            predicted position is recomputed exactly as predict() rounded it, so free motion keeps its
            velocity exactly and only corrections are rounded."""
            for i in range(N()):
                if w[i] > 0:
                    x_pred = xp[i] + dt * v[i]
                    v[i] = v[i] + (x[i] - x_pred) / dt
                else:
                    v[i] = vfix[i]

        reaction = self.reaction

        @ti.kernel
        def reactions(dt: float):
            """Force [N] the supports exert on the body through each pinned vertex: minus the constraint
            forces lambda grad C / dt^2 of the last substep acting on it."""
            inv_dt2 = 1.0 / (dt * dt)
            for i in range(n):
                reaction[i] = ti.Vector.zero(float, D)
            for cs in ti.static((self.stretch, self.bend_dist)):
                for k in range(cs.k):
                    i, j = cs.f_idx[k][0], cs.f_idx[k][1]
                    d = x[i] - x[j]
                    length = d.norm()
                    if length > eps:
                        fo = cs.f_lam[k] * inv_dt2 * d / length
                        if w[i] == 0:
                            reaction[i] -= fo
                        if w[j] == 0:
                            reaction[j] += fo

        body_off, stat_speed, stat_bad = self.body_off, self.stat_speed, self.stat_bad
        nb = len(self.entities)
        f64 = self.f == ti.f64

        if self.sources is None:
            frame_stats = make_body_frame_stats(nb, body_off, x, v, stat_speed, stat_bad, f64)
        else:  # active mode: a particle's entity by its pid (sinks move particles between slots)
            finite = make_finite(f64)
            pid = self.pid

            @ti.kernel
            def frame_stats():
                for b in range(nb):
                    stat_speed[b] = 0.0
                    stat_bad[b] = 0
                for i in range(N()):
                    p = pid[i]
                    b = 0
                    for k in range(nb):
                        if body_off[k] <= p:
                            b = k
                    if finite(x[i]) and finite(v[i]):
                        ti.atomic_max(stat_speed[b], v[i].norm())
                    else:
                        ti.atomic_add(stat_bad[b], 1)

        self._predict, self._reset, self._contact = predict, reset_multipliers, contact
        self._update_velocity, self._reactions, self._frame_stats = update_velocity, reactions, frame_stats

    # -------------------------------------------------------------- stepping
    def substep(self, dt: float) -> None:
        if self.poses.needed:  # collider poses of this substep (host, no sync)
            self.poses.set_time(self.time, dt)
        self._predict(dt)
        self._reset()
        if self.serial:
            self._project_serial(dt, self.opts.stretch_iterations, self.opts.bending_iterations)
        elif self._solve_stretch is not None:
            for _ in range(self.opts.stretch_iterations):
                self._solve_stretch(dt)
                if self._solve_volume is not None:
                    self._solve_volume(dt)
        if not self.serial and (self._solve_bend_dist is not None or self._solve_dihedral is not None):
            for _ in range(self.opts.bending_iterations):
                if self._solve_bend_dist is not None:
                    self._solve_bend_dist(dt)
                if self._solve_dihedral is not None:
                    self._solve_dihedral(dt)
        for liq in self.liquids:
            liq.project(self._clamp)
        if self.contact is not None:
            self.contact.step()
        self._contact(True)
        self._update_velocity(dt)
        if self.restitution.any:  # colliders with restitution: the bounce (simcli.collider_mesh)
            self.restitution.apply(dt)
        for liq in self.liquids:
            liq.after_velocity(dt)
        self.time += dt
        self.last_dt = dt

    def _clamp(self) -> None:
        self._contact(False)

    def frame_check(self) -> dict[str, FrameStats]:
        self._frame_stats()
        return frame_stats_per_body(
            [e.name for e in self.entities], self.stat_speed.to_numpy(), self.stat_bad.to_numpy()
        )

    def stable_dt(self, horizon: float = 0.0) -> float:
        """XPBD is unconditionally stable; contact needs a vertex to move less than its radius per
        substep to be caught before it crosses a thin collider: half the smallest radius / largest speed
        (of the particles and of the moving colliders' surfaces)."""
        self._frame_stats()
        vmax = float(np.max(self.stat_speed.to_numpy()))
        if self.poses.any_moving and math.isfinite(vmax):  # a moving collider's surface counts too
            vmax = max(vmax, self.poses.max_surface_speed(self.time))
        if self.sources is not None and math.isfinite(vmax):  # what an emitter will bring in
            vmax = max([vmax] + [float(e["cfg"].speed) for e in self.sources.emitters])
        if not math.isfinite(vmax) or vmax <= 0:
            return math.inf
        return 0.5 * float(self.radius.min()) / vmax

    def collider_loads(self) -> dict[str, np.ndarray]:
        """Named collider -> impulse [N s] and its moment [N m s] the particles gave it since the last call
        (the opposite of the final contact projection's momentum change, -m dx / dt, per substep)."""
        return self.poses.loads_by_name() if self._built else {}

    def length_scale(self) -> float:
        return max(self.edge, self.opts.particle_size)

    # ---------------------------------------------------------------- output
    def entity_kind(self, name: str) -> str:
        return self.meshes[self._index[name]].kind

    def entity_cells(self, name: str):
        m = self.meshes[self._index[name]]
        return None if m.kind == "particles" else m.cells

    def entity_size(self, name: str) -> int:
        return self.meshes[self._index[name]].n

    def owns(self, name: str) -> bool:
        return name in self._index

    def default_fields(self, name: str) -> list[str]:
        tets = self.meshes[self._index[name]].kind == "tets"
        return ["position", "velocity", "displacement"] if tets else ["position", "velocity"]

    def output_fields(self) -> dict[str, tuple[int, str]]:
        D = self.dim  # 2D: two components (masses and forces per metre of depth)
        return {
            "position": (D, "m"),
            "velocity": (D, "m/s"),
            "reaction": (D, "N"),
            "displacement": (D, "m"),
            "density": (1, "kg/m^3"),
        }

    def _live_slots(self, k: int) -> np.ndarray:
        """Active mode: the slots of entity k's live particles, in pid order (the order they entered, unless a
        reusing emitter handed out a freed pid again)."""
        lo, hi = self.offsets[k], self.offsets[k + 1]
        pid = self.pid.to_numpy()[: self.sources.n_active]
        slots = np.flatnonzero((pid >= lo) & (pid < hi))
        return slots[np.argsort(pid[slots], kind="stable")]

    def live_masses(self, name: str) -> np.ndarray:
        """Masses [kg] of an entity's live particles (probes' totals)."""
        k = self._index[name]
        if self.sources is None:
            return np.asarray(self.mass[self.offsets[k] : self.offsets[k + 1]], dtype=np.float64)
        return self.mass_f.to_numpy()[self._live_slots(k)].astype(np.float64)

    def entity_arrays(self, name: str, fields: list[str]) -> dict[str, np.ndarray]:
        k = self._index[name]
        lo, hi = self.offsets[k], self.offsets[k + 1]
        if self.sources is not None:
            return self._entity_arrays_active(k, fields)
        out = {}
        for fld in fields:
            if fld == "position":
                a = self.x.to_numpy()
            elif fld == "velocity":
                a = self.v.to_numpy()
            elif fld == "displacement":
                a = self.x.to_numpy() - self.x0
            elif fld == "density":
                a = np.zeros(self.n)
                for liq in self.liquids:
                    a[liq.lo : liq.hi] = liq.rho.to_numpy()
            elif fld == "reaction":
                if self.last_dt > 0:
                    self._reactions(self.last_dt)
                    a = self.reaction.to_numpy()
                else:
                    a = np.zeros((self.n, self.dim))
            else:
                raise KeyError(f"unknown PBD output field {fld!r}; known: {', '.join(OUTPUT_FIELDS)}")
            out[fld] = np.array(a[lo:hi])
        return out

    def _entity_arrays_active(self, k: int, fields: list[str]) -> dict[str, np.ndarray]:
        slots = self._live_slots(k)
        out = {}
        for fld in fields:
            if fld == "position":
                a = self.x.to_numpy()
            elif fld == "velocity":
                a = self.v.to_numpy()
            elif fld == "displacement":  # from where each particle started (an emitted one: entered)
                a = self.x.to_numpy() - self.x0_f.to_numpy()
            elif fld == "density":
                a = self.liquids[0].rho.to_numpy() if self.liquids else np.zeros(self.n)
                a = np.where(self.lid.to_numpy() >= 0, a, 0.0)
            elif fld == "reaction":
                if self.last_dt > 0:
                    self._reactions(self.last_dt)
                    a = self.reaction.to_numpy()
                else:
                    a = np.zeros((self.n, self.dim))
            else:
                raise KeyError(f"unknown PBD output field {fld!r}; known: {', '.join(OUTPUT_FIELDS)}")
            out[fld] = np.array(a[slots])
        return out

    # ----------------------------------------------------------------- state
    def _state_fields(self) -> dict:
        """Active mode: every per-particle field that carries state (compaction moves them)."""
        d = {"x0": self.x0_f, "w": self.w, "vfix": self.vfix_f, "rad": self.rad, "drag": self.drag_f}
        d.update(pid=self.pid, mass=self.mass_f, lid=self.lid)
        if self.contact is not None:
            d.update(body=self.body_f, mu_s=self.mus, mu_k=self.muk)
        for k, liq in enumerate(self.liquids):
            d[f"rho{k}"] = liq.rho
        return d

    def get_state(self) -> dict[str, np.ndarray]:
        d = {
            "x": self.x.to_numpy(),
            "v": self.v.to_numpy(),
            "time": np.array([self.time]),
            "last_dt": np.array([self.last_dt]),
        }
        if self.sources is not None:
            d.update({f"src_{k}": fld.to_numpy() for k, fld in self._state_fields().items()})
            d.update(self.sources.get_state())
        return d

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        for key, fld in (("x", self.x), ("v", self.v)):
            upload_state_array(fld, state, key, (self.n, self.dim), self.npf, "PBD")
        self.time = float(np.asarray(state.get("time", [0.0])).reshape(-1)[0])
        self.last_dt = float(np.asarray(state.get("last_dt", [0.0])).reshape(-1)[0])
        if self.sources is not None:
            self.sources.set_state(state)
            for k, fld in self._state_fields().items():
                if f"src_{k}" not in state:
                    raise ValueError(
                        f"PBD state: the checkpoint has no {k!r} (written without emitters or sinks)"
                    )
                arr = np.asarray(state[f"src_{k}"])
                have = fld.to_numpy()  # (shape and dtype, vector components included)
                if arr.shape != have.shape:
                    raise ValueError(f"PBD state {k!r}: shape {arr.shape} does not fit {have.shape}")
                fld.from_numpy(arr.astype(have.dtype))
            self._n_seen = self.sources.n_active
            self.active_changed()

    def counts(self) -> dict[str, int]:
        free = sum(m.n for m in self.meshes if m.kind == "particles")  # PBD.Particle and PBD.Liquid
        if self.sources is not None:  # the live ones (capacity: counts_capacity)
            free = self.sources.n_active - self.n_meshed
            return {
                "vertices": self.n_meshed,
                "particles": free,
                "constraints": self.stretch.k + self.bend_dist.k + self.dihedral.k + self.volume.k,
            }
        return {
            "vertices": self.n - free,
            "particles": free,
            "constraints": self.stretch.k + self.bend_dist.k + self.dihedral.k + self.volume.k,
        }

    def info(self) -> dict[str, Any]:
        return {
            "method": "XPBD, Gauss-Seidel by graph colouring",
            "vertices": self.n,
            "sweeps": "one single-threaded launch per substep" if self.serial else "one launch per sweep",
            "stretch_constraints": self.stretch.k,
            "stretch_colours": self.stretch.colours,
            "bending_constraints": self.bend_dist.k + self.dihedral.k,
            "bending_colours": self.bend_dist.colours + self.dihedral.colours,
            "stretch_iterations": self.opts.stretch_iterations,
            "volume_constraints": self.volume.k,
            "volume_colours": self.volume.colours,
            "bending_iterations": self.opts.bending_iterations,
            "warnings": self.warnings,
            **(
                {
                    "liquid": [
                        {
                            "rest_density": lq.rho0,
                            "smoothing_length": lq.h,
                            "neighbour_overflow": int(lq.overflow[None]),
                        }
                        for lq in self.liquids
                    ]
                }
                if self.liquids
                else {}
            ),
        }
