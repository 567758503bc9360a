"""MLS-MPM solver (Hu et al. 2018, "A Moving Least Squares Material Point Method with
Displacement Discontinuity and Two-Way Rigid Body Coupling"), APIC transfers (or FLIP/PIC with
``solvers.mpm.transfer: flip``, see transfer.py), quadratic B-splines, 2D and 3D, f32 and f64.

A substep is four named operators, in the paper's order, one module each::

    clear_grid -> p2g -> grid_update -> g2p      (p2g.py, grid_update.py, g2p.py; kernels.py composes)

Their builders take the explicit bundle of fields.py (``MPMParams``, ``MPMFields``), not this solver;
this module allocates the fields, builds the bundle and the kernels, and implements the Solver
interface (stepping, stable substep, outputs, state). The constitutive laws and their return mappings
live in constitutive.py / plasticity.py / fluid_muscle.py (dispatch: laws.py), the grid boundary in
boundary.py, the per-frame kernels in outputs.py.

Design choices (measured on a 2-core CPU, see benchmarks/mpm_micro.py):

* **Grid work over the blocks that hold material.** The grid is a dense array over the domain
  plus ``PAD`` cells, but ``clear_grid`` and ``grid_update`` only visit the blocks of 4^3 (2D: 8^2)
  nodes the particles' stencils touch, inside the particles' node box (blocks.py: g2p flags the
  blocks where it computes the box from the new positions, on the device: no host sync, no extra
  pass). Every grid field is 0 off the flagged blocks (P2G's chunk tasks and the grid update zero what
  the last substep wrote), so loops that still sweep the box (the coupling phase) see what a box sweep
  wrote. ``grid_blocks = False`` sweeps the whole box instead (the comparison in the tests).
* **P2G without atomics on the CPU.** Particles are split into ``T`` contiguous chunks
  (T = threads); chunk t scatters into its own copy t of the grid with plain read-add-write, and
  ``grid_update`` sums the copies in a fixed order. This removes the atomic float adds (a
  compare-and-swap loop each on x86) and makes a run bitwise reproducible for a given thread
  count. Each copy is cleared and summed only over its own chunk's bounding box. Taichi runs
  a top-level range-for in tasks of >= 512 iterations on the CPU, so the chunk loop is written
  as ``for j in range(T * 512): if j % 512 == 0`` to get one task per chunk; correctness does not
  depend on that mapping (each chunk owns its copy), only the parallel speed-up does.
  On GPUs the solver uses a single grid and atomic adds instead.
* **Stress fused into p2g**, from the deformation gradient updated in g2p (F <- (I + dt C) F).
* **Corotated rotation without SVD**: a warm-started quaternion rotation extraction
  (Mueller et al. 2016) whose quaternion per particle is part of the restart state.
* **Plastic laws decompose F once per substep**: their return mapping (end of g2p) also computes
  the Kirchhoff stress from the same singular values and keeps it per particle for the next p2g
  (``constitutive.py``, ``plasticity.py``). Only the laws of the materials present are compiled.
* **Colliders act twice**: on grid nodes (contact conditions, in grid_update) and on particles
  after advection (a particle inside a collider goes back to its surface; compiled only when
  colliders exist).
* **Hardening (snow) with substeps: auto**: the runner picks the substep once per frame; an
  impact can stiffen snow a hundredfold within a frame, so such scenes check stability every
  substep and subdivide it when needed (one small reduction per substep, only there).
* Particle state is struct-of-arrays (one field per quantity).
"""

import math
from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.scene.output_fields import FIELDS
from simcli.solvers.base import (
    Body,
    FrameStats,
    Solver,
    frame_stats_per_body,
    initial_positions,
    upload_state_array,
)
from simcli.solvers.mpm.blocks import BlockFields
from simcli.solvers.mpm.boundary import GridBoundary
from simcli.solvers.mpm.constitutive import ConstitutiveLaw, elastic_moduli, law_key
from simcli.solvers.mpm.cpic import CPIC, cpic_indices
from simcli.solvers.mpm.fields import MPMFields, MPMParams
from simcli.solvers.mpm.kernels import build_kernels
from simcli.solvers.mpm.laws import LAWS
from simcli.solvers.mpm.transfer import FlipTransfer
from simcli.solvers.probe_view import ProbeView
from simcli.solvers.sources import ActiveSet, has_sources

with stdout_to_stderr():
    import taichi as ti

PAD = 3  # grid cells beyond each domain face (the wall band)
MAX_PRIVATE_GRID_BYTES = 1 << 30  # memory allowed for the per-thread grid copies of P2G
WAVE_SAFETY = 0.5  # dt <= WAVE_SAFETY * dx / c_p, c_p the P-wave speed (B1 runs at 0.47)

OUTPUT_FIELDS = FIELDS["MPM"]  # the Taichi-free table validate checks (simcli/scene/output_fields.py)
# the fields the per-frame `outputs` kernel computes together
DERIVED_FIELDS = ("J", "stress", "pressure", "Jp", "elastic_energy")


class MPMSolver(Solver):
    """The MPM family: every entity with an ``MPM.*`` material."""

    family = "mpm"

    def __init__(self, scene: Any, bodies: list[Body], scene_dir: Any = None) -> None:
        super().__init__(scene, bodies)
        self.scene_dir = scene_dir  # motion files of colliders are relative to it
        if not bodies:
            raise ValueError("MPMSolver needs at least one body")
        self.dim = int(scene.sim.dim)
        self.precision = scene.sim.precision
        opts = scene.solvers.mpm
        self.dx = float(opts.dx)
        self.inv_dx = 1.0 / self.dx
        self.cfl = float(opts.cfl)
        # velocity transfer (compile-time): "apic" or "flip" (FLIP/PIC blend, see transfer.py)
        self.transfer = str(getattr(opts, "transfer", "apic"))
        self.flip_ratio = float(getattr(opts, "flip_ratio", 0.99))
        lo, hi = scene.domain.bounds(self.dim)
        self.domain_lo = np.asarray(lo, dtype=np.float64)
        self.domain_hi = np.asarray(hi, dtype=np.float64)
        if np.any(self.domain_hi <= self.domain_lo):
            raise ValueError(f"domain: lower {lo} must be below upper {hi} on every axis")

        # grid layout: node I at origin + I dx; domain faces at nodes lo_node / hi_node
        self.origin = self.domain_lo - PAD * self.dx
        ncells = np.ceil((self.domain_hi - self.domain_lo) / self.dx - 1e-6).astype(int)
        self.lo_node = tuple([PAD] * self.dim)
        self.hi_node = tuple(int(PAD + c) for c in ncells)
        self.grid_shape = tuple(int(h + PAD + 1) for h in self.hi_node)

        # bodies: contiguous particle ranges
        names = [b.name for b in bodies]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate body names: {names}")
        self.offsets = np.cumsum([0] + [b.n for b in bodies]).astype(np.int64)
        self.n = int(self.offsets[-1])
        if self.n == 0:
            raise ValueError("MPMSolver: the bodies hold no particles")
        self._index = {b.name: k for k, b in enumerate(bodies)}
        for b in bodies:
            if b.dim != self.dim:
                raise ValueError(f"body {b.name!r} has dimension {b.dim}, the scene {self.dim}")

        # materials: one id per distinct material config, one law per distinct model
        self.materials: list[Any] = []
        body_mid = []
        for b in bodies:
            mat = b.entity.material
            if mat not in self.materials:
                self.materials.append(mat)
            body_mid.append(self.materials.index(mat))
        self.body_mid = body_mid
        self.law_keys: list[str] = []
        for mat in self.materials:
            key = law_key(mat)
            if key not in LAWS:
                raise ValueError(f"MPM material model {key!r} is not implemented")
            if key not in self.law_keys:
                self.law_keys.append(key)
        self.mat_law = [self.law_keys.index(law_key(m)) for m in self.materials]
        self.has_fixed = any(bool(np.any(b.fixed)) for b in bodies)

        # P-wave speed of each material at rest (hardening and muscle activation raise it: see
        # stable_dt), and the explicit viscosity limit dt <= rho dx^2 / (2 d eta)
        self.mat_wave = []
        dt_visc = math.inf
        for m in self.materials:
            mu, lam = elastic_moduli(m)
            self.mat_wave.append(math.sqrt((lam + 2.0 * mu) / float(m.rho)))
            if getattr(m, "viscous", False) and m.mu > 0:
                dt_visc = min(dt_visc, float(m.rho) * self.dx**2 / (2.0 * self.dim * m.mu))
        self.c_max = max(self.mat_wave)
        self.dt_visc = dt_visc
        self.time = 0.0  # simulated time [s] at the start of the next substep (muscle actuation)
        # "auto": private grid copies on the CPU, atomics elsewhere; "atomic" forces the GPU path
        # (tests run it on the CPU), "chunked" the CPU one
        self.p2g_mode = "auto"
        # grid work over the blocks of nodes the particles' stencils touch (blocks.py); False: over the
        # particles' node box (the same numbers: tests compare the two)
        self.grid_blocks = True
        # emitters and sinks (simcli/solvers/sources.py): an active count; None in scenes without them
        self.sources = ActiveSet(scene, bodies, "MPM") if has_sources(scene, "MPM") else None
        self.active_set = self.sources
        # coupling between families (simcli/coupling/): set by the coupler before build; then the grid keeps
        # each node's mass (grid_m) for the coupling phase. Off: nothing below changes.
        self.store_node_mass = False
        self._built = False

    # ------------------------------------------------------------------ build

    def build(self) -> None:
        if self._built:
            return
        cfg = ti.lang.impl.current_cfg()
        self.f = ti.f64 if self.precision == "f64" else ti.f32
        self.npf = np.float64 if self.precision == "f64" else np.float32
        self.arch = str(cfg.arch).split(".")[-1]
        cpu = self.arch in ("x64", "arm64")
        threads = int(getattr(cfg, "cpu_max_num_threads", 1) or 1)
        if self.p2g_mode not in ("auto", "chunked", "atomic"):
            raise ValueError(f"p2g_mode must be auto, chunked or atomic, not {self.p2g_mode!r}")
        if self.p2g_mode == "chunked" and not cpu:
            raise ValueError("p2g_mode 'chunked' needs the CPU backend")
        T = max(1, min(threads, self.n))
        copy_bytes = int(np.prod(self.grid_shape)) * (self.dim + 2) * (8 if self.precision == "f64" else 4)
        if self.transfer == "flip":  # the grid copies also carry the momentum without the stress impulse
            copy_bytes += int(np.prod(self.grid_shape)) * self.dim * (8 if self.precision == "f64" else 4)
        if self.p2g_mode == "auto":
            # private copies cost T grids of memory: beyond the budget, atomics on one grid
            self.chunked = cpu and T * copy_bytes <= MAX_PRIVATE_GRID_BYTES
        else:
            self.chunked = self.p2g_mode == "chunked"
        self.T = T if self.chunked else 1
        dim, f, n, T = self.dim, self.f, self.n, self.T

        # particles (struct of arrays)
        self.x = ti.Vector.field(dim, f, shape=n)
        self.v = ti.Vector.field(dim, f, shape=n)
        self.C = ti.Matrix.field(dim, dim, f, shape=n)
        self.F = ti.Matrix.field(dim, dim, f, shape=n)
        self.mass = ti.field(f, shape=n)
        self.vol = ti.field(f, shape=n)
        self.mid = ti.field(ti.i32, shape=n)
        self.fixed = ti.field(ti.u8, shape=n) if self.has_fixed else None
        self.pid = ti.field(ti.i32, shape=n) if self.sources is not None else None  # identity (sources.py)

        # grid: T private copies of (momentum, mass[, fixed mass]) + the updated velocity
        self.gdim = dim + 1 + (1 if self.has_fixed else 0)
        self.flip = (
            FlipTransfer(dim, f, self.grid_shape, self.flip_ratio) if self.transfer == "flip" else None
        )
        if self.flip is not None:
            self.gdim = self.flip.allocate(self.gdim)
        self.boundary = GridBoundary(
            self.scene, dim, f, self.origin, self.dx, self.lo_node, self.hi_node, self.scene_dir
        )
        self.gap_aff = False
        self.gap_ch = -1  # the material position channels of the frictional colliders' gap test
        if self.boundary.uses_gap:
            self.gap_ch = self.gdim
            self.gdim += dim
            if self.transfer != "flip" and self.boundary.uses_gap_test:  # APIC: the nodes' affine momentum
                # too, for the gap test's contact on the material's velocity (boundary._node)
                self.gap_aff = True
                self.boundary.material_velocity = True
                self.gdim += dim
        self.cpic_ch = -1  # the ghost momentum and mass of CPIC colliders (cpic.py)
        if cpic_indices(self.scene):
            self.cpic_ch = self.gdim
            self.gdim += dim + 1
        self.grid = ti.Vector.field(self.gdim, f, shape=(T,) + self.grid_shape)
        self.grid_v = ti.Vector.field(dim, f, shape=self.grid_shape)
        self.grid_m = ti.field(f, shape=self.grid_shape) if self.store_node_mass else None
        self.bbox = ti.Vector.field(dim, ti.i32, shape=(T, 2))  # per chunk [lo, hi) node box
        self.bbox_all = ti.Vector.field(dim, ti.i32, shape=2)
        self.chunk_start = ti.field(ti.i32, shape=T + 1)
        self.blocks = BlockFields.allocate(dim, self.grid_shape, T) if self.grid_blocks else None

        # run-time parameters
        nm = len(self.materials)
        self.gravity = ti.Vector.field(dim, f, shape=())
        self.mat_mu = ti.field(f, shape=nm)
        self.mat_lam = ti.field(f, shape=nm)
        self.mat_law_id = ti.field(ti.i32, shape=nm)

        # per-entity frame statistics and outputs
        nb = len(self.bodies)
        self.body_offsets = ti.field(ti.i32, shape=nb + 1)
        self.stat_speed = ti.field(f, shape=nb)
        self.stat_bad = ti.field(ti.i32, shape=nb)
        self.stat_stiff = ti.field(f, shape=())  # largest stiffness factor (snow hardening)
        self._out = None  # per-particle output fields, allocated when first written

        self.laws: list[ConstitutiveLaw] = [LAWS[k](dim, f) for k in self.law_keys]
        for law in self.laws:
            law.allocate(n)
            law.allocate_materials(self.materials)
        self.boundary.allocate()
        # CPIC colliders (cpic.py): only scenes with one compile it
        self.cpic = None
        if cpic_indices(self.scene):
            self.cpic = CPIC(self.boundary, self.scene, dim, f, self.origin, self.dx)
            self.cpic.allocate()
            self.cpic.bind(self.grid, self.bbox, T, self.gravity, self.cpic_ch)

        self._upload()
        for law in self.laws:
            law.bind(self)
        self.count = self._count_func()
        self.wave_factor = max(law.max_wave_factor(self.materials) for law in self.laws)
        self.stiff_cap = max(law.max_stiffness_factor(self.materials) for law in self.laws)
        # a hardening law (snow) can stiffen a hundredfold within one frame of an impact, which the
        # runner's once-per-frame choice cannot foresee: with substeps: auto the solver then checks
        # every substep and subdivides it when the hardening made it unstable
        self.guard_hardening = self.stiff_cap > 1.0 and self.scene.sim.substeps == "auto"
        # the kernels (kernels.py), built from the explicit bundle, not from this object
        self.params, self.fields = self._bundle()
        self.kernels = build_kernels(
            self.params, self.fields, self.laws, self.boundary, self.flip, self.count, self.cpic
        )
        self._outputs = None  # the derived-outputs kernel, built on first use
        self.kernels.compute_bbox()
        self._built = True
        self._version = 0
        self._cache: dict = {}
        # the per-frame check runs before the first step: compile it now, with the build.
        # (the J/stress output kernel compiles on first use: only scenes that write them pay)
        self.frame_check()

    def _upload(self) -> None:
        npf = self.npf
        xs = initial_positions(self.bodies, self.domain_lo, self.domain_hi, 1e-9 * self.dx, "MPMSolver")
        self.x.from_numpy(np.clip(xs, self.domain_lo, self.domain_hi).astype(npf))
        self.v.from_numpy(np.concatenate([b.v for b in self.bodies]).astype(npf))
        # self.F stores the displacement gradient H = F - I, not F: near the rest state F's entries
        # are ~1, whose f32 spacing (1.2e-7) is the size of a stiff body's per-substep strain
        # increment, so accumulating F itself rounds the strain away or biases it (a slow creep
        # over 1e5 substeps); H keeps full relative precision for small strains.
        self.F.from_numpy(np.zeros((self.n, self.dim, self.dim), npf))
        self.C.from_numpy(np.zeros((self.n, self.dim, self.dim), npf))
        self.mass.from_numpy(np.concatenate([b.mass for b in self.bodies]).astype(npf))
        self.vol.from_numpy(np.concatenate([b.volume for b in self.bodies]).astype(npf))
        self.mid.from_numpy(
            np.concatenate([np.full(b.n, m, np.int32) for b, m in zip(self.bodies, self.body_mid)])
        )
        if self.fixed is not None:
            self.fixed.from_numpy(np.concatenate([b.fixed for b in self.bodies]).astype(np.uint8))
        self.chunk_start.from_numpy(
            (np.arange(self.T + 1, dtype=np.int64) * self.n_live() // self.T).astype(np.int32)
        )
        if self.pid is not None:
            self.pid.from_numpy(np.arange(self.n, dtype=np.int32))
        self.body_offsets.from_numpy(self.offsets.astype(np.int32))
        self.set_gravity(self.scene.sim.gravity_vec)
        self.mat_mu.from_numpy(np.array([elastic_moduli(m)[0] for m in self.materials], npf))
        self.mat_lam.from_numpy(np.array([elastic_moduli(m)[1] for m in self.materials], npf))
        self.mat_law_id.from_numpy(np.array(self.mat_law, np.int32))
        for law in self.laws:
            law.init_state()

    def _count_func(self):
        """The particle loops' bound: the active count with emitters or sinks, else the constant n."""
        if self.sources is None:
            n = self.n

            @ti.func
            def count():
                return n

            return count
        src = self.sources
        persistent = [self.x, self.v, self.C, self.F, self.mass, self.vol, self.mid, self.pid]
        persistent += [self.fixed] if self.fixed is not None else []
        for law in self.laws:  # the laws' per-particle state (Jp, rotation, stress, ...)
            for fld in vars(law).values():
                if isinstance(fld, ti.Field) and fld.shape[:1] == (self.n,) and fld not in persistent:
                    persistent.append(fld)
        mids = [self.body_mid[e["body"]] for e in src.emitters]
        vol = src.spacing**self.dim
        masses = [float(self.materials[m].rho) * vol for m in mids]
        for e, m in zip(src.emitters, masses):
            e["mass"] = m
        src.build(self, persistent, {self.mass: masses, self.vol: [vol] * len(mids), self.mid: mids}, self.f)
        return src.count_func()

    def n_live(self) -> int:
        """Particles in the simulation now (the active count)."""
        return self.n if self.sources is None else self.sources.n_active

    def active_changed(self) -> None:
        """After emission or removal: the chunks of p2g and the node boxes follow the new count."""
        self.chunk_start.from_numpy(
            (np.arange(self.T + 1, dtype=np.int64) * self.n_live() // self.T).astype(np.int32)
        )
        self.kernels.compute_bbox()
        self._version += 1

    def set_gravity(self, g: list[float]) -> None:
        """Gravity is run-time data: changing it does not recompile anything."""
        if len(g) != self.dim:
            raise ValueError(f"gravity needs {self.dim} components")
        self.gravity[None] = [float(c) for c in g]

    # ---------------------------------------------------------------- kernels

    def _bundle(self) -> tuple[MPMParams, MPMFields]:
        """The explicit bundle the kernel builders take (fields.py): compile-time constants and fields."""
        params = MPMParams(
            dim=self.dim,
            dtype=self.f,
            dx=self.dx,
            origin=tuple(float(o) for o in self.origin),
            domain_lo=tuple(float(o) for o in self.domain_lo),
            domain_hi=tuple(float(o) for o in self.domain_hi),
            grid_shape=tuple(self.grid_shape),
            T=self.T,
            chunked=self.chunked,
            gdim=self.gdim,
            has_fixed=self.has_fixed,
            n_bodies=len(self.bodies),
            gap_ch=self.gap_ch,
            gap_aff=self.gap_aff,
            block_list=self.blocks is not None,
        )
        fields = MPMFields(
            x=self.x,
            v=self.v,
            C=self.C,
            F=self.F,
            mass=self.mass,
            vol=self.vol,
            mid=self.mid,
            fixed=self.fixed,
            pid=self.pid,
            grid=self.grid,
            grid_v=self.grid_v,
            grid_m=self.grid_m,
            bbox=self.bbox,
            bbox_all=self.bbox_all,
            chunk_start=self.chunk_start,
            gravity=self.gravity,
            mat_mu=self.mat_mu,
            mat_lam=self.mat_lam,
            mat_law_id=self.mat_law_id,
            body_offsets=self.body_offsets,
            stat_speed=self.stat_speed,
            stat_bad=self.stat_bad,
            stat_stiff=self.stat_stiff,
            blocks=self.blocks,
        )
        return params, fields

    # ---------------------------------------------------------------- stepping

    def splits_substep(self) -> bool:
        # hardening (snow) under substeps: auto: the stable substep can shrink within a frame, so the runner's
        # substep policy cuts each substep to this family's stable_dt (one reduction and a host read per
        # substep, only in such scenes)
        return self.guard_hardening

    def substep(self, dt: float) -> None:
        for law in self.laws:  # muscle activations at the start of the substep (host, no sync)
            law.host_update(self.time, dt)
        if self.boundary.any_moving:  # collider poses of this substep (host, no sync)
            self.boundary.set_time(self.time, dt)
        if self.cpic is not None:
            self.cpic.set_time(self.time, dt)
        self.kernels.substep(dt)  # clear_grid -> p2g -> grid_update -> g2p, one kernel launch
        self.time += dt
        self._version += 1

    # Coupled scenes (simcli/coupling/): the same substep in two phases around the coupling phase, which
    # edits grid_v between them: pre_couple = muscle, collider poses, clear_grid -> p2g -> grid_update;
    # post_couple = g2p. The hardening split (splits_substep) is not applied in coupled scenes: the
    # runner's auto substep, which asks stable_dt, bounds the substep instead.

    def pre_couple(self, dt: float) -> None:
        for law in self.laws:
            law.host_update(self.time, dt)
        if self.boundary.any_moving:
            self.boundary.set_time(self.time, dt)
        if self.cpic is not None:
            self.cpic.set_time(self.time, dt)
        self.kernels.pre_couple(dt)

    def post_couple(self, dt: float) -> None:
        self.kernels.stage_g2p(dt)
        self.time += dt
        self._version += 1

    # ------------------------------------------------------------ frame checks

    def frame_check(self) -> dict[str, FrameStats]:
        self.kernels.frame_stats()
        return frame_stats_per_body(
            [b.name for b in self.bodies], self.stat_speed.to_numpy(), self.stat_bad.to_numpy()
        )

    def stable_dt(self, horizon: float = 0.0) -> float:
        """min(cfl dx / max particle speed, WAVE_SAFETY dx / c_p, viscosity limit) [s]; one reduction
        kernel. c_p is the P-wave speed of the stiffest material, raised by the largest current
        hardening factor (snow) and by the largest muscle activation."""
        self.kernels.frame_stats()
        vmax = float(np.max(self.stat_speed.to_numpy()))
        if self.sources is not None:  # what an emitter will bring in
            vmax = max([vmax] + [float(e["cfg"].speed) for e in self.sources.emitters])
        if self.boundary.any_moving:  # a moving collider must not cross more than cfl cells a substep either
            vmax = max(vmax, self.boundary.poses.max_surface_speed(self.time))
        stiff = min(self.stiff_cap, max(1.0, float(self.stat_stiff[None]))) * self.wave_factor
        c = self.c_max * math.sqrt(stiff)
        dt_wave = WAVE_SAFETY * self.dx / c if c > 0 else math.inf
        dt_cfl = self.cfl * self.dx / vmax if vmax > 0 else math.inf
        return float(min(dt_wave, dt_cfl, WAVE_SAFETY * self.dt_visc))

    # ------------------------------------------------------------------ output

    def _full(self, key: str) -> np.ndarray:
        hit = self._cache.get(key)
        if hit is not None and hit[0] == self._version:
            return hit[1]
        if key == "position":
            arr = self.x.to_numpy()
        elif key == "velocity":
            arr = self.v.to_numpy()
        elif key in DERIVED_FIELDS:
            if self._outputs is None:
                self._outputs = self.kernels.make_outputs(self._derived_fields())
            self._outputs()
            for name, fld in zip(DERIVED_FIELDS, self._out):
                self._cache[name] = (self._version, fld.to_numpy())
            return self._cache[key][1]
        elif key == "material_id":
            arr = self.mid.to_numpy()
        elif key == "mass":
            arr = self.mass.to_numpy()
        else:
            raise KeyError(f"unknown MPM output field {key!r}; known: {', '.join(OUTPUT_FIELDS)}")
        self._cache[key] = (self._version, arr)
        return arr

    def entity_arrays(self, name: str, fields: list[str]) -> dict[str, np.ndarray]:
        k = self._index[name]
        lo, hi = int(self.offsets[k]), int(self.offsets[k + 1])
        if self.sources is not None:  # the entity's live particles (active slots), in pid order
            hit = self._cache.get("pid")
            if hit is None or hit[0] != self._version:
                self._cache["pid"] = (self._version, self.pid.to_numpy())
            pid = self._cache["pid"][1][: self.sources.n_active]
            sel = np.flatnonzero((pid >= lo) & (pid < hi))
            sel = sel[np.argsort(pid[sel], kind="stable")]
            return {fld: np.array(self._full(fld)[sel]) for fld in fields}
        return {fld: np.array(self._full(fld)[lo:hi]) for fld in fields}

    def probe_view(self) -> ProbeView:
        """Positions and fields by slot for the probes' device path (simcli/probes/device.py); the derived
        fields (J, pressure, ...) are computed only at the slots a probe reads."""
        rng = {name: (int(self.offsets[k]), int(self.offsets[k + 1])) for name, k in self._index.items()}
        return ProbeView(
            x=self.x,
            key=self.pid,
            n_live=self.n_live,
            ranges=rng,
            field=self._probe_field,
            dtype=self.npf,
            derived=DERIVED_FIELDS,
            derive=self.kernels.make_derive(self._derived_fields()),
        )

    def _derived_fields(self) -> tuple:
        if self._out is None:  # allocated on first use: only scenes that write or probe them pay
            self._out = tuple(ti.field(self.f, shape=self.n) for _ in DERIVED_FIELDS)
        return self._out

    def _probe_field(self, key: str):
        if key == "position":
            return self.x
        if key == "velocity":
            return self.v
        if key in DERIVED_FIELDS:
            return self._derived_fields()[DERIVED_FIELDS.index(key)]
        raise KeyError(key)

    # ------------------------------------------------------------------- state

    def get_state(self) -> dict[str, np.ndarray]:
        # the field stores H = F - I (see _upload): the state carries H exactly (bit-for-bit restart)
        # and F = I + H in float64 for readers
        H = self.F.to_numpy()
        F = np.eye(self.dim) + H.astype(np.float64)
        state = {
            "x": self.x.to_numpy(),
            "v": self.v.to_numpy(),
            "C": self.C.to_numpy(),
            "F": F,
            "H": H,
            "time": np.array([self.time]),
        }
        for law in self.laws:
            state.update(law.get_state())
        if self.sources is not None:  # what emission and removal change besides the above
            state.update(
                mass=self.mass.to_numpy(),
                vol=self.vol.to_numpy(),
                mid=self.mid.to_numpy(),
                pid=self.pid.to_numpy(),
            )
            if self.fixed is not None:
                state["fixed"] = self.fixed.to_numpy()
            state.update(self.sources.get_state())
        return state

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        npf = self.npf
        shapes = {
            "x": (self.n, self.dim),
            "v": (self.n, self.dim),
            "C": (self.n, self.dim, self.dim),
            "H": (self.n, self.dim, self.dim),
        }
        # H as saved, unless only F is given or F was changed after get_state
        F = np.asarray(state["F"], dtype=np.float64)
        H = state.get("H")
        if H is None or not np.array_equal(F, np.eye(self.dim) + np.asarray(H, dtype=np.float64)):
            state = dict(state, H=F - np.eye(self.dim))
        for key, fld in (("x", self.x), ("v", self.v), ("C", self.C), ("H", self.F)):
            upload_state_array(fld, state, key, shapes[key], npf, "MPM")
        for law in self.laws:
            law.set_state(state)
        if "time" in state:
            self.time = float(np.asarray(state["time"]).reshape(-1)[0])
        if self.sources is not None:
            self.sources.set_state(state)
            for key, fld, dt in (
                ("mass", self.mass, npf),
                ("vol", self.vol, npf),
                ("mid", self.mid, np.int32),
                ("pid", self.pid, np.int32),
                ("fixed", self.fixed, np.uint8),
            ):
                if fld is not None:
                    upload_state_array(fld, state, key, (self.n,), dt, "MPM")
            self.chunk_start.from_numpy(
                (np.arange(self.T + 1, dtype=np.int64) * self.n_live() // self.T).astype(np.int32)
            )
        self.kernels.compute_bbox()
        self._version += 1

    def length_scale(self) -> float:
        return self.dx

    def collider_loads(self) -> dict[str, np.ndarray]:
        """Named collider -> (dim + 3) impulse [N s] and its moment about the collider's moving pivot
        [N m s] that the material gave it since the last call (the opposite of what the contact gave the
        material, summed over the grid nodes and substeps); resets them."""
        if not self._built or not self.boundary.any_named:
            return {}
        a = self.boundary.take_loads()
        return {c.name: a[k] for k, c in enumerate(self.boundary.colliders) if c.name is not None}

    def collider_poses(self):
        return self.boundary.poses if self._built else None

    def output_fields(self) -> dict[str, tuple[int, str]]:
        d = self.dim
        return {
            "position": (d, "m"),
            "velocity": (d, "m/s"),
            "J": (1, "1"),
            "stress": (1, "Pa"),
            "pressure": (1, "Pa"),
            "Jp": (1, "1"),
            "elastic_energy": (1, "J"),
            "mass": (1, "kg"),
            "material_id": (1, "1"),
        }

    # ------------------------------------------------------------------ counts

    def counts(self) -> dict[str, int]:
        active = box = 0
        if self._built:  # node box and nodes the next substep works on (union over the chunks)
            b = self.bbox.to_numpy()
            box = int(np.prod(np.maximum(b[:, 1].max(axis=0) - b[:, 0].min(axis=0), 0)))
            # the nodes the grid work visits: the last substep's block list (blocks.py), else the box
            if self.blocks is not None:  # the blocks the current particles' stencils touch, in the box
                x = self.x.to_numpy()[: self.n_live()].astype(np.float64)
                base = np.floor((x - self.origin) * self.inv_dx - 0.5).astype(np.int64)
                base = np.clip(base, 0, np.asarray(self.grid_shape) - 3)
                active = self.blocks.nodes(base, b[:, 0].min(axis=0), b[:, 1].max(axis=0))
            else:
                active = box
        return {
            "particles": self.n_live(),
            "grid_cells": int(np.prod(self.grid_shape)),
            "grid_copies": self.T if self._built else 0,
            "active_cells": active,
            "box_cells": box,
        }

    def info(self) -> dict[str, Any]:
        return {
            "transfer": (
                f"MLS-MPM / FLIP-PIC blend (flip_ratio {self.flip_ratio}), quadratic B-splines"
                if self.transfer == "flip"
                else "MLS-MPM / APIC, quadratic B-splines"
            ),
            "grid": (
                f"dense {self.grid_shape}, work limited to the blocks of {self.blocks.edge}^{self.dim} nodes "
                "the particles touch"
                if self.blocks is not None
                else f"dense {self.grid_shape}, work limited to the particles' bounding box"
            ),
            "p2g": f"{self.T} private grid copies, no atomics" if self.chunked else "atomic adds",
            "laws": list(self.law_keys),
            "colliders": [c.kind for c in self.boundary.colliders] if self._built else [],
        }
