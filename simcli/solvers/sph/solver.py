"""SPH solver family: weakly compressible (WCSPH) and divergence-free (DFSPH) liquids, 2D and 3D, f32
and f64, boundary particles for walls and colliders.

A substep reads like the paper (see wcsph.py and dfsph.py)::

    neighbours -> density -> non_pressure -> pressure_solve -> advect

This module allocates the fields, makes the explicit bundle the kernel builders take (bundle.py: SPHParams,
SPHFields, SPHFuncs), calls the builders and implements the Solver interface. The operators, one module each:

* neighbours.py: cell grid rebuilt by a counting sort each substep, particles reordered by cell;
  stencil.py: the cell stencil walked by every pass, particle mass and volume;
* density.py: per-particle neighbour lists with the kernel gradients, density, and the boundary sums;
* boundary.py: domain walls and colliders as static boundary particles (Akinci et al. 2012), sampled
  volume-correctly; their contributions are summed once per substep into a few per-particle values
  (density, sum V_b grad W_ib, and for no-slip walls a viscous matrix), so later passes cost nothing;
* non_pressure.py (gravity, viscosity, surface tension; WCSPH's pressure force in the same pass), advect.py;
* wcsph.py, dfsph.py: the pressure solvers' substeps; wall_pressure.py: extrapolated wall pressure;
  moving.py: moving colliders and the loads on named colliders; outputs.py: frame check, stable_dt's inputs;
* kernels.py: cubic spline with support radius 2 x particle_size.

Non-pressure accelerations: gravity, viscosity (physical mu, Monaghan 2005 Laplacian, also against
no-slip boundaries) and surface tension (Akinci et al. 2013: cohesion kernel + curvature from surface
normals, with the symmetric correction factor 2 rho0 / (rho_i + rho_j)).

Particles are stored in cell order (``pid`` maps back to the entity order the writers get).
"""

import dataclasses
import json
import math
from typing import Any

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.scene.output_fields import FIELDS
from simcli.solvers.base import Body, FrameStats, Solver, frame_stats_per_body, initial_positions
from simcli.solvers.probe_view import ProbeView
from simcli.solvers.sources import ActiveSet, has_sources, is_emitter
from simcli.solvers.sph.advect import make_advect
from simcli.solvers.sph.boundary import make_pushout, sample_boundary
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams
from simcli.solvers.sph.density import make_neighbours_density
from simcli.solvers.sph.dfsph import SolveStats, make_dfsph
from simcli.solvers.sph.kernels import lattice_sum, make_kernels
from simcli.solvers.sph.moving import make_loads, make_moving_boundary
from simcli.solvers.sph.neighbours import CellGrid, make_neighbour_funcs, neighbour_capacity
from simcli.solvers.sph.non_pressure import make_non_pressure
from simcli.solvers.sph.outputs import make_outputs
from simcli.solvers.sph.stencil import make_stencil
from simcli.solvers.sph.wall_pressure import make_wall_pressure
from simcli.solvers.sph.wcsph import make_wcsph

with stdout_to_stderr():
    import taichi as ti

OUTPUT_FIELDS = FIELDS["SPH"]  # the Taichi-free table validate checks (simcli/scene/output_fields.py)
# dt <= VISCOUS_SAFETY particle_size^2 / nu: explicit viscosity is stable up to 0.14 ps^2 / nu for the SPH
# Laplacian on a lattice (support 2, checkerboard mode; 0.31 at support 3), about half that next to a
# no-slip wall; 0.05 leaves room for disorder.
VISCOUS_SAFETY = 0.05


class SPHSolver(Solver):
    """The SPH family: every entity with an ``SPH.*`` material."""

    family = "sph"

    def __init__(self, scene: Any, bodies: list[Body], scene_dir: Any = None) -> None:
        if not bodies:
            raise ValueError("SPHSolver needs at least one body")
        # (scene_dir: collider motion files are relative to it; warnings: what the placement below changed)
        super().__init__(scene, bodies, scene_dir)
        self.time = 0.0  # simulated time at the start of the next substep [s] (moving colliders)
        self.removed: dict[str, dict[str, float]] = {}
        if scene.colliders:
            bodies = self._place_inside_colliders(scene, bodies)
            self.bodies = list(bodies)
        self.ti = ti
        self.dim = int(scene.sim.dim)
        self.precision = scene.sim.precision
        self.opts = scene.solvers.sph
        self.ps = float(self.opts.particle_size)
        self.support = float(self.opts.support_radius)
        lo, hi = scene.domain.bounds(self.dim)
        self.domain_lo = np.asarray(lo, dtype=np.float64)
        self.domain_hi = np.asarray(hi, dtype=np.float64)
        names = [b.name for b in bodies]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate body names: {names}")
        self.offsets = np.cumsum([0] + [b.n for b in bodies]).astype(np.int64)
        self.n = int(self.offsets[-1])
        if self.n == 0:
            raise ValueError("SPHSolver: the bodies hold no particles")
        self._index = {b.name: k for k, b in enumerate(bodies)}
        self.materials: list[Any] = []
        self.body_mid = []
        for b in bodies:
            if b.dim != self.dim:
                raise ValueError(f"body {b.name!r} has dimension {b.dim}, the scene {self.dim}")
            if b.entity.material not in self.materials:
                self.materials.append(b.entity.material)
            self.body_mid.append(self.materials.index(b.entity.material))
        self.c_max = max(math.sqrt(m.stiffness * m.exponent / m.rho) for m in self.materials)
        self.nu_max = max(m.mu / m.rho for m in self.materials)
        self.has_viscosity = self.nu_max > 0
        self.has_tension = any(m.gamma > 0 for m in self.materials)
        self.g_norm = float(np.linalg.norm(scene.sim.gravity_vec))
        # rest volume of a particle [m^dim]: the lattice cell over the kernel's lattice sum, so that a lattice
        # of liquid (and of wall particles) sits at rho0 exactly
        self.V_rest = self._rest_volume(scene)
        self.fall_height = float(
            np.linalg.norm(self.domain_hi - self.domain_lo)
        )  # longest drop in the domain
        self.dfsph_stats = SolveStats()
        self.dt_limits: dict[str, Any] = {
            "checks": 0,
            "bound_by": {},
            "sum_dt": 0.0,
            "sum_sound_share": 0.0,
            "sum_compression_factor": 0.0,
        }
        # emitters and sinks (simcli/solvers/sources.py): an active count; None in scenes without them
        self.sources = ActiveSet(scene, bodies, "SPH") if has_sources(scene, "SPH") else None
        self.active_set = self.sources
        # a deformable body's boundary particles (deformable.py), attached by the coupling phase before build
        self.deformable = None
        self.bsrc = None
        self._built = False

    def _place_inside_colliders(self, scene: Any, bodies: list[Body]) -> list[Body]:
        """Particles sampled inside a collider (centre at signed distance < 0), per body, on the host before
        anything is allocated. solvers.sph.inside_colliders: remove drops them. push_out moves each onto the
        surface along the direction the collider's own signed distance gives (the run-time guard's,
        simcli.colliders) and drops its inward normal velocity; a particle that this would put outside the
        domain (a collider flush with a domain wall: it would land on the wall, still inside the collider) is
        dropped instead. Records how many were dropped and their mass for the warning and run.json."""
        from simcli.colliders import collider_motions, collider_specs
        from simcli.colliders import inside_normal_np as inside_normal_numpy
        from simcli.colliders import sdf_np as sdf_numpy

        dim = int(scene.sim.dim)
        specs = collider_specs(scene, dim, self.scene_dir)
        pose0 = [None if m is None else m.pose(0.0) for m in collider_motions(scene, dim, self.scene_dir)]
        lo, hi = (np.asarray(v, dtype=np.float64) for v in scene.domain.bounds(dim))
        push = scene.solvers.sph.inside_collider_mode == "push_out"
        margin = 0.25 * float(scene.solvers.sph.particle_size)
        out = []
        for b in bodies:
            if is_emitter(b):  # reserved slots, not yet in the liquid
                out.append(b)
                continue
            x, v = b.x.copy(), b.v.copy()
            drop = np.zeros(b.n, bool)
            for spec, p0 in zip(specs, pose0):
                xb = x if p0 is None else p0.to_body(x)  # a moving collider: its pose at t = 0
                phi = sdf_numpy(spec, xb)
                hit = np.flatnonzero((phi < 0.0) & ~drop)
                if not push:
                    drop[hit] = True
                    continue
                nrm = inside_normal_numpy(spec, xb[hit])
                if p0 is not None:
                    nrm = nrm @ p0.R.T
                target = x[hit] - phi[hit, None] * nrm
                ok = np.all((target >= lo + margin) & (target <= hi - margin), axis=1)
                drop[hit[~ok]] = True
                x[hit[ok]] = target[ok]
                vn = np.einsum("ij,ij->i", v[hit[ok]], nrm[ok])
                v[hit[ok]] -= np.minimum(vn, 0.0)[:, None] * nrm[ok]
            for spec, p0 in zip(specs, pose0):  # pushed out of one collider into another: none left inside
                drop |= (
                    sdf_numpy(spec, x if p0 is None else p0.to_body(x)) < -1e-6 * margin
                )  # (the pushed ones lie on a surface, to round-off)
            k = int(drop.sum())
            if k == b.n > 0:
                from simcli.errors import SceneError

                hint = "" if push else " or set solvers.sph.inside_colliders: push_out"
                msg = (
                    f"entity '{b.name}': every particle lies inside a collider; "
                    "move the entity out of the collider"
                )
                raise SceneError([msg + hint])
            if k:
                mass = float(k) * b.entity.material.rho * self._rest_volume(scene)
                unit = "kg" if dim == 3 else "kg per metre of depth"
                self.removed[b.name] = {"particles": k, "of": b.n, "mass_kg": mass}
                why = (
                    "pushing them onto the collider's surface would put them outside the domain (a collider "
                    "against a domain wall)"
                    if push
                    else "solvers.sph.inside_colliders: remove, the default with DFSPH"
                )
                self.warnings.append(
                    f"{b.name}: {k} of {b.n} particles were sampled inside a collider and removed "
                    f"({mass:.4g} {unit}, {100.0 * k / b.n:.3g}%; {why}). Move the entity out of the "
                    "collider to keep them" + ("" if push else ", or set inside_colliders: push_out")
                )
            out.append(b.kept(~drop, x, v))
        return out

    def remove_inside(self, inside: Any, what: str) -> None:
        """Before build: drop the liquid's particles for which ``inside`` ((m, dim) positions -> (m,) bool)
        holds, another family's body placed in the liquid at the start (a coupling pair, sph_fem.py), as
        particles sampled inside a collider are removed; recorded with them (run.json, the warning)."""
        if self._built:
            raise RuntimeError("SPH: particles are removed before build")
        from simcli.errors import SceneError

        out = []
        for b in self.bodies:
            if is_emitter(b):
                out.append(b)
                continue
            drop = np.asarray(inside(b.x), bool)
            k = int(drop.sum())
            if k == b.n > 0:
                raise SceneError([f"entity '{b.name}': every particle lies inside {what}; move one of them"])
            if k:
                mass = float(k) * b.entity.material.rho * self.V_rest
                rec = self.removed.setdefault(b.name, {"particles": 0, "of": b.n, "mass_kg": 0.0})
                rec["particles"] += k
                rec["mass_kg"] += mass
                self.warnings.append(
                    f"{b.name}: {k} of {b.n} particles were sampled inside {what} and removed "
                    f"({mass:.4g} kg, {100.0 * k / b.n:.3g}%). Move the entity out of it to keep them"
                )
                b = b.kept(~drop)
            out.append(b)
        self.bodies = out
        self.offsets = np.cumsum([0] + [b.n for b in out]).astype(np.int64)
        self.n = int(self.offsets[-1])
        if self.sources is not None:
            self.sources = ActiveSet(self.scene, out, "SPH")
            self.active_set = self.sources

    def attach_deformable(self, db: Any) -> None:
        """Another family's body as boundary particles (deformable.py): called before build by a coupling
        pair (simcli/coupling/sph_fem.py, mpm_sph.py). Only with boundary particles (not volume maps). A
        second body joins the first (``DeformableBoundary.joined``: each keeps its offset into the shared
        fields)."""
        if self._built:
            raise RuntimeError("SPH: a deformable boundary is attached before build")
        if self.opts.boundary != "particles":
            raise ValueError("SPH: a deformable boundary needs solvers.sph.boundary: particles")
        if self.deformable is None:
            self.deformable = db
        else:
            from simcli.solvers.sph.deformable import DeformableBoundary

            self.deformable = DeformableBoundary.joined([self.deformable, db])

    @staticmethod
    def _rest_volume(scene: Any) -> float:
        """Rest volume of a particle [m^dim]: the lattice cell over the kernel's lattice sum."""
        opts = scene.solvers.sph
        dim = int(scene.sim.dim)
        return float(opts.particle_size) ** dim / lattice_sum(
            float(opts.support_radius) / float(opts.particle_size), dim
        )

    # ------------------------------------------------------------------ build

    def build(self) -> None:
        if self._built:
            return
        cfg = ti.lang.impl.current_cfg()
        self.f = f = ti.f64 if self.precision == "f64" else ti.f32
        self.npf = np.float64 if self.precision == "f64" else np.float32
        self.arch = str(cfg.arch).split(".")[-1]
        cpu = self.arch in ("x64", "arm64")
        dim, n = self.dim, self.n
        self.grid = grid = CellGrid(self.domain_lo, self.domain_hi, self.support, dim)
        # moving and named colliders (moving.py): poses per substep, loads; compiled only when needed. The
        # boundary particles, the push-out guard and the loads all follow self.poses.specs (one index k per
        # collider), so that anything driven through ColliderPoses is sampled and moved alike
        from simcli.colliders import ColliderPoses, collider_motions, collider_specs

        self.poses = ColliderPoses(
            collider_specs(self.scene, dim, self.scene_dir),
            collider_motions(self.scene, dim, self.scene_dir),
            dim,
            f,
        )
        self.poses.allocate()
        # boundary: volume_map (volume_map.py): no boundary particles; the walls' and static colliders' sums
        # are precomputed maps each liquid particle looks up in the density pass
        self.vmap = None
        if self.opts.boundary == "volume_map":
            from simcli.solvers.sph.boundary import LAYERS, BoundaryParticles
            from simcli.solvers.sph.volume_map import VolumeMap

            layers = max(LAYERS, math.ceil(self.support / self.ps - 1e-9))
            self.vmap = VolumeMap(
                self.scene, dim, self.ps, self.support, self.V_rest, self.poses.specs, layers
            )
            z = np.zeros((0, dim))
            bp = BoundaryParticles(z, np.zeros(0), z, np.zeros(0, bool), np.zeros(0, np.int32))
        else:
            bp = sample_boundary(self.scene, dim, self.ps, self.support, self.poses.specs)
        db = self.deformable
        src = np.full(bp.n, -1, np.int32)
        if db is not None and db.n:  # a deformable body's samples after the walls and colliders (collider -2)
            from simcli.solvers.sph.boundary import BoundaryParticles

            bp = BoundaryParticles(
                np.concatenate([bp.x, db.x]),
                np.concatenate([bp.volume, db.volume]),
                np.concatenate([bp.velocity, db.velocity]),
                np.concatenate([bp.no_slip, np.zeros(db.n, bool)]),
                np.concatenate([bp.col, np.full(db.n, -2, np.int32)]),
            )
            src = np.concatenate([src, np.arange(db.n, dtype=np.int32)])
        keep = grid.inside_np(bp.x)
        if self.poses.any_moving:  # a moving collider's whole shell: it may enter the grid later
            keep |= np.isin(bp.col, [k for k, c in enumerate(self.poses.specs) if c.moving])
        keep |= src >= 0  # a deformable body's samples too
        order, bstart = grid.sort_static(bp.x[keep])
        self.nbp = int(keep.sum())
        self.K = neighbour_capacity(dim, self.support / self.ps)
        self.has_noslip = bool(np.any(bp.no_slip[keep])) and self.has_viscosity
        if self.vmap is not None:
            self.has_noslip = self.vmap.no_slip and self.has_viscosity

        # particles, in cell order
        vec = lambda: ti.Vector.field(dim, f, shape=n)
        scal = lambda: ti.field(f, shape=n)
        self.x, self.v, self.vnew = vec(), vec(), vec()
        self.mass, self.rho, self.p = scal(), scal(), scal()
        self.mid = ti.field(ti.i32, shape=n)
        self.pid = ti.field(ti.i32, shape=n)
        self.B = vec()
        self.Sb = scal()
        self.nb_cnt = ti.field(ti.i32, shape=n)
        self.nbb_cnt = ti.field(ti.i32, shape=n)
        self.nb_j = ti.field(ti.i32, shape=(n, self.K))
        # grad W_ij per list entry: DFSPH walks the list in every iteration and keeps it; WCSPH walks it once
        # more (the force pass, which loads x_j anyway) and recomputes it there: 4 instead of 16 (3D) bytes
        # per entry, a quarter of the list's memory and traffic
        self.store_grad = self.opts.pressure_solver == "DFSPH"
        # DFSPH: grad W_ij's factor per list entry (grad W_ij = (x_i - x_j) s_ij; bundle.py)
        # WCSPH on the CPU keeps it too (its force pass then skips the kernel's q, branch and division per
        # pair, which the neighbour pass has computed already: docs/PERFORMANCE_SPH.md, 2026-11-27); on a
        # GPU it recomputes, where the list's traffic costs more than the arithmetic
        self.list_s = self.store_grad or cpu
        self.nb_s = ti.field(f, shape=(n, self.K)) if self.list_s else None
        self.nrm = vec() if self.has_tension else None
        self.Mv = ti.Matrix.field(dim, dim, f, shape=n) if self.has_noslip else None
        self.shift = vec() if self.opts.shifting > 0 else None
        self.mw = vec() if self.has_noslip else None
        dfsph = self.opts.pressure_solver == "DFSPH"
        self.alpha = scal() if dfsph else None
        # extrapolated wall pressure (wall_pressure.py): each liquid particle's boundary neighbours follow its
        # liquid ones in its neighbour list (up to nbw_end), and it flags the boundary particles it
        # reaches, so
        # that only those list their liquid neighbours
        self.ext_walls = self.opts.wall_model == "extrapolated"
        # volume maps with DFSPH's extrapolated wall pressure: each particle's hydrostatic wall term (once
        # per substep; volume_map.py)
        self.Hb = vec() if self.vmap is not None and self.ext_walls else None
        # ... WCSPH: each particle's mirrored wall pressure, relaxing towards its own (wcsph.py)
        self.pw = scal() if self.Hb is not None and not dfsph else None
        # delta-SPH (delta_sph.py; WCSPH): the continuity density's rate and the renormalised density gradient
        self.continuity = not dfsph and self.opts.density == "continuity"
        dd = self.opts.density_diffusion
        self.diffusion_model = dd.model if (dd is not None and self.continuity) else ""
        self.drho = scal() if self.continuity else None
        self.grad_rho = vec() if self.diffusion_model == "antuono" else None
        # WCSPH, one material: p / rho^2 per particle, written with the pressure, so that the force pass's
        # pairs read it instead of dividing p_j by rho_j^2 each
        self.pr2 = scal() if (not dfsph and len(self.materials) == 1) else None
        # ... and m / rho, the viscosity's pair coefficient (a division per pair less)
        self.m_rho = scal() if (self.pr2 is not None and self.has_viscosity) else None
        self.nbw_end = ti.field(ti.i32, shape=n) if self.ext_walls else None
        self.bflag = ti.field(ti.i32, shape=max(1, self.nbp)) if self.ext_walls else None
        # kernel gradient correction L_i (Bonet & Lok 1999) of the DFSPH pressure solves
        self.kgc = dfsph and bool(self.opts.gradient_correction_mode)
        # gradient_correction: scalar keeps one number per particle (L_i = c_i I): a cheaper pass than
        # the matrix
        self.kgc_scalar = self.kgc and self.opts.gradient_correction_mode == "scalar"
        self.Lm = ti.Matrix.field(dim, dim, f, shape=n) if self.kgc and not self.kgc_scalar else None
        self.Lc = scal() if self.kgc_scalar else None
        self.kk = scal() if dfsph else None
        self.kacc = scal() if dfsph else None
        self.kappa = scal() if dfsph else None
        self.kappav = scal() if dfsph else None
        self.err_acc = ti.field(ti.i64, shape=())
        self.overflow = ti.field(ti.i32, shape=())

        # reorder buffers and cells
        move = [self.x, self.v, self.mass, self.mid, self.pid] + ([self.kappa, self.kappav] if dfsph else [])
        move_tmp = [
            ti.Vector.field(dim, f, shape=n),
            ti.Vector.field(dim, f, shape=n),
            scal(),
            ti.field(ti.i32, shape=n),
            ti.field(ti.i32, shape=n),
        ] + ([scal(), scal()] if dfsph else [])
        if self.pw is not None:
            move.append(self.pw)
            move_tmp.append(scal())
        if self.continuity:  # the density is a state: it moves with its particle in the cell sort
            move.append(self.rho)
            move_tmp.append(scal())
        self.cell_id = ti.field(ti.i32, shape=n)
        self.rank = ti.field(ti.i32, shape=n)
        self.count = ti.field(ti.i32, shape=grid.ncells)
        self.start = ti.field(ti.i32, shape=grid.ncells + 1)
        self.block_sum = ti.field(ti.i32, shape=grid.nblocks)
        self.sort, self.cell_coords, self.linear = make_neighbour_funcs(
            grid,
            f,
            cpu,
            {
                "x": self.x,
                "move": move,
                "move_tmp": move_tmp,
                "cell_id": self.cell_id,
                "rank": self.rank,
                "count": self.count,
                "start": self.start,
                "block_sum": self.block_sum,
            },
        )

        # boundary particles, in cell order
        nbp = max(1, self.nbp)
        self.bx = ti.Vector.field(dim, f, shape=nbp)
        self.bV = ti.field(f, shape=nbp)
        self.bvel = ti.Vector.field(dim, f, shape=nbp)
        self.bns = ti.field(ti.i32, shape=nbp)
        self.bstart = ti.field(ti.i32, shape=grid.ncells + 1)
        self.bnear = ti.field(ti.i8, shape=grid.ncells)  # a boundary particle lies in the cell's stencil
        self.bx0 = ti.Vector.field(dim, f, shape=nbp) if self.poses.needed else None  # body frame
        self.bcol = ti.field(ti.i32, shape=nbp) if self.poses.needed else None  # collider, -1: walls
        if db is not None:  # each boundary particle's sample of the deformable body, -1: none
            self.bsrc = ti.field(ti.i32, shape=nbp)
            db.allocate(dim, f, self.npf)
        npf = self.npf
        if self.nbp:
            self.bx.from_numpy(bp.x[keep][order].astype(npf))
            self.bV.from_numpy((bp.volume[keep][order] * (self.V_rest / self.ps**dim)).astype(npf))
            self.bvel.from_numpy(bp.velocity[keep][order].astype(npf))
            self.bns.from_numpy(bp.no_slip[keep][order].astype(np.int32))
        self.bstart.from_numpy(bstart.astype(np.int32))
        self.bnear.from_numpy(grid.dilate(np.diff(bstart) > 0).astype(np.int8))
        if self.poses.needed and self.nbp:
            self.bx0.from_numpy(bp.x[keep][order].astype(npf))
            self.bcol.from_numpy(bp.col[keep][order].astype(np.int32))
        if self.bsrc is not None and self.nbp:
            self.bsrc.from_numpy(src[keep][order])
        deform = db is not None and db.n > 0
        self.moving_boundary = (self.poses.any_moving or deform) and self.nbp > 0
        self.named_loads = (self.poses.any_named or deform) and (self.nbp > 0 or self.vmap is not None)
        # which cells have a boundary particle in reach (density.py skips the boundary scan elsewhere): with a
        # moving boundary (a collider in motion, a rigid body, a deformable body's samples), the walls' and
        # still colliders' cells (kept here) and those within reach of a moving boundary particle, marked
        # again every substep (moving.py)
        self.bnear_static = None
        if self.moving_boundary:
            moving_cols = [k for k, c in enumerate(self.poses.specs) if c.moving]
            fixed = keep & (src < 0) & ~np.isin(bp.col, moving_cols)
            occupied = np.bincount(grid.cell_index_np(bp.x[fixed]), minlength=grid.ncells) > 0
            self.bnear_static = ti.field(ti.i8, shape=grid.ncells)
            self.bnear_static.from_numpy(grid.dilate(occupied).astype(np.int8))

        # materials and run-time parameters
        nm = len(self.materials)
        self.mat_rho0, self.mat_k, self.mat_n = ti.field(f, nm), ti.field(f, nm), ti.field(f, nm)
        self.mat_nu, self.mat_gamma = ti.field(f, nm), ti.field(f, nm)
        self.gravity = ti.Vector.field(dim, f, shape=())
        self.col_fields = (
            ti.Vector.field(dim, f, shape=max(1, len(self.poses.specs))),
            ti.Vector.field(dim, f, shape=max(1, len(self.poses.specs))),
            ti.field(f, shape=max(1, len(self.poses.specs))),
            ti.field(f, shape=max(1, len(self.poses.specs))),
        )
        nb = len(self.bodies)
        self.body_offsets = ti.field(ti.i32, shape=nb + 1)
        self.stat_speed = ti.field(f, shape=nb)
        self.stat_bad = ti.field(ti.i32, shape=nb)
        # stable_dt's inputs, read in one transfer: the largest finite particle speed and (WCSPH) the largest
        # rho / rho0 of the last density pass
        self.stat_dt = ti.field(f, shape=2)

        self.pushout, upload_colliders, _ = make_pushout(
            self.scene,
            dim,
            f,
            self.col_fields,
            self.poses if self.poses.any_moving else None,
            self.poses.specs,
        )
        upload_colliders()
        self._upload()
        self.count = self._count_func()
        self._make_kernels()
        self._built = True
        self._version = 0
        self._cache: dict = {}
        self._density_only()  # the density stable_dt reads before the first substep
        if self.continuity:  # the continuity equation's initial density: a liquid at rest's
            self._hydrostatic_density()
        if self._pressure_from_density is not None:
            # frame 0's pressure: Tait's of that density (DFSPH's exists after a solve)
            self._pressure_from_density()
        self.frame_check()

    def _upload(self) -> None:
        npf = self.npf
        xs = initial_positions(self.bodies, self.domain_lo, self.domain_hi, 1e-9 * self.ps, "SPHSolver")
        self.x.from_numpy(np.clip(xs, self.domain_lo, self.domain_hi).astype(npf))
        self.v.from_numpy(np.concatenate([b.v for b in self.bodies]).astype(npf))
        # mass = rho0 V_rest: the mass that gives rho0 on the sampling lattice; the body's exact-volume mass
        # would put a curved body off rest density
        self.mass.from_numpy(
            np.concatenate([np.full(b.n, b.entity.material.rho * self.V_rest) for b in self.bodies]).astype(
                npf
            )
        )
        mids = np.concatenate([np.full(b.n, m, np.int32) for b, m in zip(self.bodies, self.body_mid)])
        self.mid.from_numpy(mids)
        self.pid.from_numpy(np.arange(self.n, dtype=np.int32))
        self.body_offsets.from_numpy(self.offsets.astype(np.int32))
        for fld, vals in (
            (self.mat_rho0, [m.rho for m in self.materials]),
            (self.mat_k, [m.stiffness for m in self.materials]),
            (self.mat_n, [m.exponent for m in self.materials]),
            (self.mat_nu, [m.mu / m.rho for m in self.materials]),
            (self.mat_gamma, [m.gamma for m in self.materials]),
        ):
            fld.from_numpy(np.asarray(vals, npf))
        if self.kappa is not None:
            n0 = self.n if self.sources is None else self.sources.n0  # emitters' slots: no warm start
            k0 = np.zeros(self.n)
            if n0:
                k0[:n0] = self._hydrostatic_stiffness(xs[:n0], mids[:n0])
            self.kappa.from_numpy(k0.astype(npf))
            self.kappav.fill(0)
        self.set_gravity(self.scene.sim.gravity_vec)

    def _hydrostatic_density(self) -> None:
        """density: continuity (delta_sph.py): each particle starts at the density whose Tait pressure is
        the hydrostatic pressure of its depth, rho0 (1 + rho0 g depth / k)^(1 / n), as delta-SPH's dam
        breaks start (Marrone et al. 2011); the summed density would leave the free surface's deficient
        sum in the state for good. Called after the density pass's sort: in the particles' cell order."""
        n0 = self.n_live()
        xs = self.x.to_numpy()[:n0].astype(np.float64)
        mids = self.mid.to_numpy()[:n0]
        rho = self.rho.to_numpy()
        rho0 = np.array([m.rho for m in self.materials], dtype=np.float64)[mids]
        k = np.array([m.stiffness for m in self.materials], dtype=np.float64)[mids]
        ex = np.array([m.exponent for m in self.materials], dtype=np.float64)[mids]
        p = rho0 * self._hydrostatic_stiffness(xs, mids, split=True) if n0 else np.zeros(0)
        rho[:n0] = rho0 * (1.0 + p / k) ** (1.0 / ex)
        rho[n0:] = 0.0
        self.rho.from_numpy(rho.astype(self.npf))

    def _hydrostatic_stiffness(self, xs: np.ndarray, mids: np.ndarray, split: bool = False) -> np.ndarray:
        """The DFSPH density solve's first warm start: the stiffness k = p / rho0 = |g| depth of a liquid at
        rest, depth measured below the top of each particle's column (bins of one particle size across the
        gravity direction; with several liquids p integrates each one's rho0 g down the column). A column
        released at rest has this pressure from its first instant (incompressible liquid); without it the
        first substeps must build it from zero with a Jacobi solver, which needs
        O(layers^2) iterations.

        ``split`` (the continuity density's start, where the density is state, not a warm start): a column
        is cut where its particles are more than 1.5 particle sizes apart, so a drop above a pool or liquid
        under a shelf does not count the gap and what is above it; and a piece with nothing under it (no
        boundary particle and not the domain's floor within 1.5 particle sizes below its lowest particle: a
        falling drop) starts at zero pressure."""
        g = np.asarray(self.scene.sim.gravity_vec, dtype=np.float64)
        gn = float(np.linalg.norm(g))
        if gn == 0.0:
            return np.zeros(len(xs))
        up = -g / gn
        height = xs @ up
        # coordinates across gravity, binned: particles of one vertical column share a key
        basis = np.linalg.svd(np.eye(self.dim) - np.outer(up, up))[0][:, : self.dim - 1]
        keys = np.floor((xs @ basis) / self.ps + 0.5).astype(np.int64)
        _, col = np.unique(keys, axis=0, return_inverse=True)
        col = col.reshape(-1)
        if split:
            return self._split_column_stiffness(mids, up, gn, basis, keys, col, height)
        top = np.full(col.max() + 1, -np.inf)
        np.maximum.at(top, col, height)
        if len(self.materials) == 1:
            depth = top[col] + 0.5 * self.ps - height
            return gn * depth
        # several liquids: integrate rho0 g down each column (trapezoid between neighbours in the column, half
        # a particle size of the top particle's own liquid above it), then k_i = p_i / rho0_i
        rho0 = np.array([m.rho for m in self.materials], dtype=np.float64)[mids]
        o = np.lexsort((-height, col))  # by column, then from the top down
        c, h, r = col[o], height[o], rho0[o]
        first = np.r_[True, c[1:] != c[:-1]]  # the top particle of each column
        inc = np.empty(len(o))
        inc[first] = gn * r[first] * (top[c[first]] + 0.5 * self.ps - h[first])
        inc[~first] = gn * 0.5 * (r[:-1] + r[1:])[~first[1:]] * (h[:-1] - h[1:])[~first[1:]]
        p = np.empty(len(o))
        bounds = np.r_[np.flatnonzero(first), len(o)]
        for a, b in zip(bounds[:-1], bounds[1:]):  # a running sum down each column (a loop over columns)
            p[o[a:b]] = np.cumsum(inc[a:b])
        return p / rho0

    def _split_column_stiffness(self, mids, up, gn, basis, keys, col, height) -> np.ndarray:
        """``_hydrostatic_stiffness(split=True)``: p / rho0 integrated down each connected, supported piece
        of a column (see there; ``col``: each particle's column)."""
        ps = self.ps
        o = np.lexsort((-height, col))  # by column, then from the top down
        c, h = col[o], height[o]
        start = np.r_[True, (c[1:] != c[:-1]) | (h[:-1] - h[1:] > 1.5 * ps)]  # a piece's top particle
        seg = np.cumsum(start) - 1
        ends = np.r_[np.flatnonzero(start)[1:] - 1, len(o) - 1]  # a piece's lowest particle (sorted index)
        bottom = h[ends]
        # what holds a piece up: the domain's floor, or a boundary particle in its column just below it
        lo, hi = np.asarray(self.scene.domain.lower, float), np.asarray(self.scene.domain.upper, float)
        corners = np.array(np.meshgrid(*zip(lo, hi), indexing="ij")).reshape(self.dim, -1).T
        supported = bottom - float((corners @ up).min()) < 1.5 * ps
        if self.nbp and not supported.all():
            bx = self.bx.to_numpy()[: self.nbp].astype(np.float64)
            bkeys = np.floor((bx @ basis) / ps + 0.5).astype(np.int64)
            bh = bx @ up
            below: dict = {}
            for kk, hh in zip(map(tuple, bkeys), bh):
                below.setdefault(kk, []).append(hh)
            seg_key = keys[o][ends]
            for sgi in np.flatnonzero(~supported):
                hs = below.get(tuple(seg_key[sgi]))
                if hs is not None:
                    d = bottom[sgi] - np.asarray(hs)
                    supported[sgi] = bool(((d > -0.5 * ps) & (d < 1.5 * ps)).any())
        rho0 = np.array([m.rho for m in self.materials], dtype=np.float64)[mids]
        r = rho0[o]
        inc = np.empty(len(o))
        inc[start] = gn * r[start] * 0.5 * ps  # half a particle size of the top particle's own liquid
        nxt = ~start[1:]
        inc[1:][nxt] = gn * 0.5 * (r[:-1] + r[1:])[nxt] * (h[:-1] - h[1:])[nxt]
        p = np.empty(len(o))
        bounds = np.r_[np.flatnonzero(start), len(o)]
        for a, b in zip(bounds[:-1], bounds[1:]):  # a running sum down each piece
            p[a:b] = np.cumsum(inc[a:b])
        p *= supported[seg]
        out = np.empty(len(o))
        out[o] = p / r
        return out

    def _count_func(self):
        """The particle loops' bound: the active count with emitters or sinks, else the constant n."""
        if self.sources is None:
            n = self.n

            @ti.func
            def count():
                return n

            return count
        src = self.sources
        persistent = [
            self.x,
            self.v,
            self.mass,
            self.mid,
            self.pid,
            self.rho,
            self.p,
        ]  # (rho, p: written out)
        persistent += [self.kappa, self.kappav] if self.kappa is not None else []
        mids = [self.body_mid[e["body"]] for e in src.emitters]
        masses = [self.materials[m].rho * self.V_rest for m in mids]
        for e, m in zip(src.emitters, masses):
            e["mass"] = float(m)
        # inflow buffer (Federico et al. 2012; Tafuni et al. 2018): the layers within one kernel support of
        # the
        # nozzle keep its prescribed motion, a piston that feeds the jet at its speed and rest spacing (a free
        # nozzle lets the newest layer's pressure push the jet back into it)
        buf = int(math.ceil(self.support / self.ps)) + 1
        consts = {self.mass: masses, self.mid: mids}
        if self.continuity:  # the continuity density's state: an emitted particle enters at rho0
            consts[self.rho] = [self.materials[m].rho for m in mids]
        src.build(self, persistent, consts, self.f, buffer_layers=buf)
        return src.count_func()

    def n_live(self) -> int:
        """Particles in the simulation now (the active count)."""
        return self.n if self.sources is None else self.sources.n_active

    def active_changed(self) -> None:
        self._version += 1

    def set_gravity(self, g: list[float]) -> None:
        if len(g) != self.dim:
            raise ValueError(f"gravity needs {self.dim} components")
        self.gravity[None] = [float(c) for c in g]

    # ---------------------------------------------------------------- kernels

    def _make_kernels(self) -> None:
        """The bundle (bundle.py: constants, fields, shared funcs) and the builders' kernels, in build order:
        smoothing kernels and stencil, the passes (density.py, non_pressure.py, advect.py), the walls'
        pressure (wall_pressure.py), moving colliders and loads (moving.py), the per-frame kernels
        (outputs.py), and the pressure solver's substep (wcsph.py or dfsph.py)."""
        self.uniform = len(self.materials) == 1
        P = self.params = self._params()
        F = self.fields = self._fields()
        fn = self.funcs = SPHFuncs(
            count=self.count,
            sort=self.sort,
            cell_coords=self.cell_coords,
            linear=self.linear,
            pushout=self.pushout,
        )
        fn.Wk, fn.gradW, fn.Ckern, fn.W_gradW = make_kernels(P.h, P.dim, P.f)
        fn.rows, fn.row_cell, fn.mass_of, fn.volume_of = make_stencil(P, F, fn)
        if self.vmap is not None:
            fn.boundary_map = self.vmap.build(
                self.f,
                self.npf,
                self.has_noslip,
                self.Hb is not None,
                self.poses if self.poses.any_moving else None,
                F,
                fn,
                with_moment=self.kgc and not self.kgc_scalar,
            )
            fn.map_wall_k = self.vmap.make_wall_k(F, fn)
        fn.neighbours_density = make_neighbours_density(P, F, fn)
        fn.non_pressure = make_non_pressure(P, F, fn)
        fn.advect = make_advect(P, F, fn)
        # extrapolated wall pressure (wall_pressure.py): only where there are walls and the option asks for it
        bodies = tuple(k for k, c in enumerate(self.poses.specs) if getattr(c, "rigid", False))
        fn.wall_pressure = make_wall_pressure(P, F, fn, bodies) if P.ext_walls and P.nbp > 0 else None
        self.wall_pressure = fn.wall_pressure
        db = self.deformable if (self.deformable is not None and self.deformable.n) else None
        if P.moving_boundary:
            fn.move_boundary, mark_near = make_moving_boundary(
                P, F, fn, self.poses, self.grid, db, self.bnear_static
            )
            if self.bnear_static is not None:

                @ti.kernel
                def refresh_near():
                    mark_near()

                self._refresh_near = refresh_near
        if P.named_loads and self.vmap is not None:  # the named static colliders' maps (volume_map.py)
            fn.load_pressure, fn.load_viscous = self.vmap.make_loads(P, F, fn, self.poses)
        elif P.named_loads:
            fn.load_pressure, fn.load_viscous = make_loads(P, F, fn, self.poses, db)
        self._frame_stats, self._density_only, self._dt_stats = make_outputs(P, F, fn, len(self.bodies), db)
        if P.dfsph:
            self._substep, self._couple_phases = make_dfsph(P, F, fn, self.dfsph_stats, self.n_live)
            self._pressure_from_density = None
        else:
            self._substep, self._pressure_from_density, self._couple_phases = make_wcsph(P, F, fn)

    def _params(self) -> SPHParams:
        o = self.opts
        return SPHParams(
            dim=self.dim,
            f=self.f,
            n=self.n,
            ps=self.ps,
            h=self.support,
            K=self.K,
            R=self.grid.R,
            grid_dims=tuple(self.grid.dims),
            domain_lo=tuple(self.domain_lo),
            domain_hi=tuple(self.domain_hi),
            wall_standoff=self.opts.wall_standoff * self.ps,
            nbp=self.nbp,
            uniform=self.uniform,
            m_c=float(self.materials[0].rho * self.V_rest),
            V_c=float(self.V_rest),
            pressure_solver=o.pressure_solver,
            store_grad=self.store_grad,
            has_viscosity=self.has_viscosity,
            has_tension=self.has_tension,
            has_noslip=self.has_noslip,
            shifting=o.shifting,
            viscosity_operator=o.viscosity_operator,
            kgc=self.kgc,
            kgc_scalar=self.kgc_scalar,
            ext_walls=self.ext_walls,
            moving_boundary=self.moving_boundary,
            named_loads=self.named_loads,
            clamp_pressure=o.clamp_pressure,
            background_pressure=o.background_pressure,
            wall_pressure_relaxation=o.wall_pressure_relaxation,
            warm_start=o.warm_start,
            divergence_solve=o.divergence_solve,
            max_divergence_error_percent=o.max_divergence_error_percent,
            max_density_error_percent=o.max_density_error_percent,
            max_divergence_iterations=o.max_divergence_iterations,
            max_density_iterations=o.max_density_iterations,
            cpu=self.arch in ("x64", "arm64"),
            volume_map=self.vmap is not None,
            continuity=self.continuity,
            diffusion_model=self.diffusion_model,
            diffusion_delta=float(o.density_diffusion.delta) if self.diffusion_model else 0.0,
            artificial_viscosity=float(o.artificial_viscosity) if o.pressure_solver == "WCSPH" else 0.0,
            int_exponent=self._int_exponent(),
        )

    def _int_exponent(self) -> int:
        """The one material's Tait exponent where it is a whole number from 1 to 16 (wcsph.py's
        equation of state multiplies then), else 0."""
        e = float(self.materials[0].exponent)
        return int(e) if (self.uniform and e.is_integer() and 1 <= e <= 16) else 0

    def _fields(self) -> SPHFields:
        names = [fld.name for fld in dataclasses.fields(SPHFields)]
        return SPHFields(**{k: getattr(self, k) for k in names})

    # ---------------------------------------------------------------- stepping

    def substep(self, dt: float) -> None:
        if self.poses.any_moving:  # collider poses of this substep (host, one small upload)
            self.poses.set_time(self.time, dt)
        self._substep(dt)
        self.time += dt
        self._version += 1

    # Coupled scenes (simcli/coupling/): pre_couple = everything up to the end-of-substep velocity
    # (couple_velocity: DFSPH's v, WCSPH's vnew), post_couple = advect; substep() is not used then.
    def pre_couple(self, dt: float) -> None:
        if self.poses.any_moving:  # collider poses of this substep (host, one small upload)
            self.poses.set_time(self.time, dt)
        self._couple_phases[0](dt)

    def post_couple(self, dt: float) -> None:
        self._couple_phases[1](dt)
        self.time += dt
        self._version += 1

    @property
    def couple_velocity(self):
        return self._couple_phases[2]

    def frame_check(self) -> dict[str, FrameStats]:
        self._frame_stats()
        return frame_stats_per_body(
            [b.name for b in self.bodies], self.stat_speed.to_numpy(), self.stat_bad.to_numpy()
        )

    def stable_dt(self, horizon: float = 0.0) -> float:
        """min(cfl ps / (v + c), VISCOUS_SAFETY ps^2 / nu, max_substep) [s], c the WCSPH sound speed at the
        largest compression now (0 for DFSPH). v is the largest particle speed now (a moving collider's or a
        deformable body's surface, where faster) plus what gravity can add
        before the next check, ``horizon`` seconds ahead (the runner's substep policy says how long: a frame,
        or the last substep with sim.auto_check: substep)."""
        self._dt_stats()
        vmax, rho_ratio = (float(s) for s in self.stat_dt.to_numpy())
        if self.sources is not None:  # what an emitter will bring in
            vmax = max([vmax] + [float(e["cfg"].speed) for e in self.sources.emitters])
        if not math.isfinite(vmax):
            return self.opts.max_substep
        if self.poses.any_moving:  # a moving collider's surface must not cross more than cfl ps either
            vmax = max(vmax, self.poses.max_surface_speed(self.time))
        # gravity cannot add more than g t over the horizon, nor more than a free fall across the domain
        v_est = min(vmax + self.g_norm * horizon, math.sqrt(vmax**2 + 2.0 * self.g_norm * self.fall_height))
        c = 0.0
        if self.opts.pressure_solver == "WCSPH":
            # Tait's sound speed at the largest compression: c0 (rho / rho0)^((n - 1) / 2) (overlapping
            # particles, an impact)
            ratio = max(1.0, rho_ratio)
            n_max = max(m.exponent for m in self.materials)
            c = self.c_max * ratio ** (0.5 * (n_max - 1.0)) if math.isfinite(ratio) else self.c_max
        limits = {"max_substep": self.opts.max_substep}
        if v_est + c > 0:
            limits["cfl"] = self.opts.cfl * self.ps / (v_est + c)
        if self.nu_max > 0:
            limits["viscous"] = VISCOUS_SAFETY * self.ps**2 / self.nu_max
        bound = min(limits, key=limits.get)
        dt = limits[bound]
        # what set the substep, for run.json: which limit, and in a CFL limit the share of the sound speed
        a = self.dt_limits
        a["checks"] += 1
        a["bound_by"][bound] = a["bound_by"].get(bound, 0) + 1
        a["sum_dt"] += dt
        if bound == "cfl":
            a["sum_sound_share"] += c / (v_est + c)
            a["sum_compression_factor"] += c / self.c_max if c > 0 else 1.0
        return float(dt)

    # ------------------------------------------------------------------ output

    def _sorted(self, key: str) -> np.ndarray:
        if key == "position":
            return self.x.to_numpy()
        if key == "velocity":
            return self.v.to_numpy()
        if key == "density":  # before the first substep: the density build() computed
            return self.rho.to_numpy()
        if key == "pressure":
            return self.p.to_numpy()
        if key == "material_id":
            return self.mid.to_numpy()
        raise KeyError(f"unknown SPH output field {key!r}; known: {', '.join(OUTPUT_FIELDS)}")

    def _full(self, key: str) -> np.ndarray:
        hit = self._cache.get(key)
        if hit is not None and hit[0] == self._version:
            return hit[1]
        if self._cache.get("pid", (None,))[0] != self._version:
            self._cache["pid"] = (self._version, self.pid.to_numpy())
        pid = self._cache["pid"][1]
        s = self._sorted(key)
        arr = np.empty_like(s)
        if self.sources is not None:  # only the active slots: the others hold stale pids
            na = self.sources.n_active
            arr[pid[:na]] = s[:na]
            self._cache[key] = (self._version, arr)
            return arr
        arr[pid] = s
        self._cache[key] = (self._version, arr)
        return arr

    def entity_arrays(self, name: str, fields: list[str]) -> dict[str, np.ndarray]:
        k = self._index[name]
        lo, hi = int(self.offsets[k]), int(self.offsets[k + 1])
        if self.sources is not None:  # the entity's live particles, in pid order
            self._full("position")
            pid = self._cache["pid"][1][: self.sources.n_active]
            live = np.sort(pid[(pid >= lo) & (pid < hi)])
            return {fld: np.array(self._full(fld)[live]) for fld in fields}
        return {fld: np.array(self._full(fld)[lo:hi]) for fld in fields}

    def probe_view(self) -> ProbeView:
        """Positions and fields by slot (sorted along the particles each substep; pid gives the output
        order) for the probes' device path (simcli/probes/device.py)."""
        fields = {"position": self.x, "velocity": self.v, "density": self.rho, "pressure": self.p}
        rng = {name: (int(self.offsets[k]), int(self.offsets[k + 1])) for name, k in self._index.items()}
        return ProbeView(
            x=self.x, key=self.pid, n_live=self.n_live, ranges=rng, field=fields.__getitem__, dtype=self.npf
        )

    # ------------------------------------------------------------------- state

    def _state_fields(self) -> dict:
        # rho: the last density pass, which stable_dt reads (WCSPH's sound speed at the largest compression),
        # so that a resumed run chooses the same substeps as an uninterrupted one
        d = {"x": self.x, "v": self.v, "mass": self.mass, "mid": self.mid, "pid": self.pid, "rho": self.rho}
        if self.kappa is not None:
            d.update(kappa=self.kappa, kappav=self.kappav)
        if self.pw is not None:
            d["wall_pressure_map"] = self.pw  # volume maps, WCSPH: the particles' relaxing wall pressure
        if self.wall_pressure is not None and self.wall_pressure.pbar is not None:
            d["wall_pressure"] = self.wall_pressure.pbar  # WCSPH's relaxing wall pressure (wall_pressure.py)
        if self.moving_boundary:  # the boundary particles' order (re-sorted every substep) and place
            d.update(bx=self.bx, bV=self.bV, bvel=self.bvel, bns=self.bns)
            if self.bx0 is not None:
                d.update(bx0=self.bx0, bcol=self.bcol)
        if self.bsrc is not None:  # a deformable body's samples: their slots, places and velocities
            d.update(bsrc=self.bsrc, deformable_x=self.deformable.sx, deformable_v=self.deformable.sv)
        return d

    def get_state(self) -> dict[str, np.ndarray]:
        d = {k: fld.to_numpy() for k, fld in self._state_fields().items()}
        if self.poses.needed:
            d["time"] = np.array([self.time])
        # run.json's solver statistics (DFSPH iterations and errors, what set the substeps, neighbour-list
        # overflow), so that a resumed run reports the whole run, not what came after the resume (JSON bytes)
        stats = {
            "dfsph": self.dfsph_stats.d,
            "dt_limits": self.dt_limits,
            "overflow": int(self.overflow[None]),
        }
        d["run_stats"] = np.frombuffer(json.dumps(stats).encode("utf-8"), dtype=np.uint8)
        if self.sources is not None:
            d.update(self.sources.get_state())
        return d

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        if self.sources is not None:  # the active count first: the density pass below runs over it
            self.sources.set_state(state)
        for k, fld in self._state_fields().items():
            if k == "rho" and k not in state:  # checkpoints written before session 6: computed below
                continue
            if k == "wall_pressure_map" and k not in state:  # a checkpoint of another boundary
                raise ValueError(
                    "SPH state: the checkpoint has no volume-map wall pressure (it was written with "
                    "solvers.sph.boundary: particles, or with DFSPH); resume it with the boundary it was "
                    "written with"
                )
            if k == "wall_pressure" and k not in state:  # a checkpoint of another wall model
                raise ValueError(
                    "SPH state: the checkpoint has no wall pressure (it was written with Akinci's walls: "
                    "WCSPH before session 8, or wall_pressure: akinci); resume it with "
                    "solvers.sph.wall_pressure: "
                    "akinci"
                )
            if k in ("bsrc", "deformable_x", "deformable_v", "bx", "bV") and k not in state:
                raise ValueError(
                    "SPH state: the checkpoint has no moving boundary or FEM body samples (it was written "
                    "before SPH met FEM bodies as boundary particles, 2026-11-27, or by another scene); run "
                    "the scene again from the start"
                )
            arr = np.asarray(state[k])
            if k in ("bx", "bV", "bvel", "bns", "bx0", "bcol", "bsrc", "deformable_x", "deformable_v"):
                # a moving boundary (moving.py), a deformable body's samples (deformable.py)
                fld.from_numpy(arr.astype(np.int32 if k in ("bns", "bcol", "bsrc") else self.npf))
                continue
            if arr.shape != fld.shape + ((self.dim,) if k in ("x", "v") else ()):
                hint = (
                    "; the scene's particle count changed (since session 6, DFSPH removes particles sampled "
                    "inside a collider: solvers.sph.inside_colliders: push_out restores the old count)"
                    if k == "x"
                    else ""
                )
                raise ValueError(f"SPH state {k!r}: shape {arr.shape} does not fit {fld.shape}{hint}")
            fld.from_numpy(arr.astype(np.int32 if k in ("mid", "pid") else self.npf))
        if getattr(self, "_refresh_near", None) is not None:  # the moving boundary's cells (moving.py)
            self._refresh_near()
        if "rho" not in state:
            self._density_only()  # sorts every per-particle field along: after all of them are loaded
        if "time" in state:
            self.time = float(np.asarray(state["time"]).reshape(-1)[0])
        # (a "frame_time" of checkpoints before session 10, stable_dt's look-ahead, is the runner's now)
        if "run_stats" in state:  # checkpoints before session 7 lack it: statistics restart at the resume
            stats = json.loads(np.asarray(state["run_stats"], dtype=np.uint8).tobytes().decode("utf-8"))
            self.dfsph_stats.d = stats["dfsph"]
            self.dt_limits = stats["dt_limits"]
            self.overflow[None] = int(stats["overflow"])
        self._version += 1

    def length_scale(self) -> float:
        return self.ps

    def runaway_advice(self, name: str, sim) -> str:
        if sim.substeps == "auto":
            advice = f"lower solvers.sph.cfl or solvers.sph.max_substep, or the stiffness of '{name}' (WCSPH)"
        else:
            advice = (
                f"use substeps: auto (it follows the CFL, sound-speed and viscous limits), lower "
                f"sim.dt (now {sim.dt:g} s) or the stiffness of '{name}' (WCSPH)"
            )
        return advice + f", or change solvers.sph.particle_size (now {self.ps:g} m)"

    def collider_loads(self) -> dict[str, np.ndarray]:
        """Named collider -> (dim + 3) impulse [N s] and its moment about the collider's moving pivot [N m s]
        the liquid gave it since the last call (the reaction of its boundary particles' pressure and no-slip
        viscosity on the liquid, moving.py); resets them."""
        return self.poses.loads_by_name() if self._built else {}

    def output_fields(self) -> dict[str, tuple[int, str]]:
        return {
            "position": (self.dim, "m"),
            "velocity": (self.dim, "m/s"),
            "density": (1, "kg/m^3"),
            "pressure": (1, "Pa"),
            "material_id": (1, "1"),
        }

    def counts(self) -> dict[str, int]:
        return {
            "particles": self.n_live(),
            "boundary_particles": self.nbp if self._built else 0,
            "cells": self.grid.ncells if self._built else 0,
        }

    def info(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "pressure_solver": self.opts.pressure_solver,
            "kernel": f"cubic spline, support radius {self.support / self.ps:g} x particle_size",
            "particle_size": self.ps,
            "neighbours": (
                f"cell grid {self.grid.dims} of {self.grid.cell:g} m, counting sort + reorder every "
                f"substep, neighbour lists of {self.K}"
            )
            if self._built
            else None,
            "inside_colliders": self.opts.inside_collider_mode,
            "removed_inside_colliders": self.removed,
            "boundary": (
                f"volume map (no boundary particles): {self.vmap.describe()}; wall pressure: "
                f"{self.opts.wall_model}"
                if self.vmap is not None
                else f"{self.nbp} boundary particles (Akinci et al. 2012), wall pressure: "
                f"{self.opts.wall_model}"
                + (
                    " (Adami et al. 2012 / Band et al. 2018)"
                    if self.opts.wall_model == "extrapolated"
                    else ""
                )
            )
            if self._built
            else None,
        }
        if self._built:
            d["neighbour_overflow"] = int(self.overflow[None])
        a = self.dt_limits
        if a["checks"]:
            ncfl = a["bound_by"].get("cfl", 0)
            d["stable_dt"] = {
                "checks": a["checks"],
                "bound_by": dict(a["bound_by"]),
                "mean_dt_s": a["sum_dt"] / a["checks"],
                # in the CFL-bound checks: c / (v + c), and c / c0 (Tait's sound speed at the largest
                # compression over the sound speed at rest)
                "cfl_sound_speed_share_mean": a["sum_sound_share"] / ncfl if ncfl else None,
                "cfl_compression_factor_mean": a["sum_compression_factor"] / ncfl if ncfl else None,
            }
        if self.opts.pressure_solver == "DFSPH":
            d["dfsph"] = self.dfsph_stats.report()
            d["tolerances_percent"] = {
                "density": self.opts.max_density_error_percent,
                "divergence": self.opts.max_divergence_error_percent,
            }
        return d
