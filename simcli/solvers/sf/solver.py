"""Stable fluids (Stam 1999, "Stable Fluids") on a MAC grid, 2D and 3D, f32 and f64.

A substep is the paper's sequence of named stages, with the forces added after the advection
(as in Bridson's book) so that the smoke and the velocity are carried by the projected, divergence-free
velocity of the last step::

    advect -> add_sources -> diffuse -> project

(Stam's order, forces first, advects the smoke by a field that still holds the unprojected body
force: a heavy layer at rest then drains through its own interface, 13 % of it in 10 s in the
validation tank.)

* ``add_sources`` (jets.py): jets (smoke, heat, imposed velocity or acceleration, moving on a
  path), exponential decay, Boussinesq buoyancy, vorticity confinement; one kernel launch.
* ``advect`` (advection.py): semi-Lagrangian with an RK3 back-trace, or MacCormack / BFECC with
  a clamp limiter, of every velocity component and the scalars; one kernel launch.
* ``diffuse`` (diffusion.py): implicit viscosity by conjugate gradients (skipped when nu = 0).
* ``project`` (projection.py): Jacobi or multigrid-preconditioned CG on the pressure, stopped
  on the divergence tolerance; iterations and the final residual of every substep are kept
  for run.json (``info()``).

The grid and boundary conditions are in grid.py and boundary.py. The SF entity is the fluid
filling the whole domain; it is read from the scene (the solver gets no sampled bodies).
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
    upload_state_array,
)
from simcli.solvers.sf.advection import Advector
from simcli.solvers.sf.boundary import Boundary
from simcli.solvers.sf.diffusion import Diffusion
from simcli.solvers.sf.grid import SOLID, collider_mask, compute_flags, make_layout
from simcli.solvers.sf.jets import Sources
from simcli.solvers.sf.moving import SFColliders
from simcli.solvers.sf.projection import Projection

with stdout_to_stderr():
    import taichi as ti

OUTPUT_FIELDS = FIELDS["SF"]  # the Taichi-free table validate checks (simcli/scene/output_fields.py)
DEFAULT_FIELDS = ["velocity", "pressure", "density", "temperature", "divergence"]
HISTORY_KEEP = 100_000  # per-substep solver records kept for run.json
_SAFE = {
    "np": np,
    "pi": math.pi,
    "sin": np.sin,
    "cos": np.cos,
    "exp": np.exp,
    "sqrt": np.sqrt,
    "tanh": np.tanh,
    "abs": np.abs,
    "where": np.where,
    "minimum": np.minimum,
    "maximum": np.maximum,
}


def eval_field(expr: str, coords: list[np.ndarray]) -> np.ndarray:
    """A numpy expression of x, y[, z] [m] (the scene's `velocity_field`) at the given points."""
    env = dict(zip("xyz", coords))
    v = eval(expr, {"__builtins__": {}}, {**_SAFE, **env})  # restricted names, no builtins
    return np.broadcast_to(np.asarray(v, dtype=np.float64), coords[0].shape)


class SFSolver(Solver):
    """The SF family: the scene's ``SF.Smoke`` entity, a fluid filling the domain grid."""

    family = "sf"

    def __init__(self, scene: Any, bodies: list[Body], scene_dir: Any = None) -> None:
        super().__init__(scene, bodies)
        self.scene_dir = scene_dir  # collider motion files are relative to it
        ents = [e for e in scene.entities if e.family == "SF"]
        if len(ents) != 1:
            raise ValueError(f"a scene holds exactly one SF.Smoke entity (found {len(ents)})")
        self.entity = ents[0]
        self.name = self.entity.name
        self.mat = self.entity.material
        self.opts = scene.solvers.sf
        self.dim = int(scene.sim.dim)
        self.precision = scene.sim.precision
        self.layout = make_layout(scene, self.opts)
        self.time = 0.0
        self.hist: dict[str, list] = {
            "iterations": [],
            "residual": [],
            "relative_residual": [],
            "viscosity_iterations": [],
            "converged": [],
        }
        self.substeps = 0
        self._built = False

    # ------------------------------------------------------------------ build

    def build(self) -> None:
        if self._built:
            return
        L = self.layout
        dim = self.dim
        self.f = ti.f64 if self.precision == "f64" else ti.f32
        self.npf = np.float64 if self.precision == "f64" else np.float32
        f = self.f
        # named and moving colliders (moving.py); still ones keep the static mask and code path
        self.cols = SFColliders(self.scene, L, self.scene_dir) if self.scene.colliders else None
        self.moving = self.cols is not None and self.cols.any_moving
        self.named = self.cols is not None and bool(self.cols.named)
        self._own = self.cols.owner(0.0) if self.moving or self.named else None
        compute_flags(L, self._own >= 0 if self.moving else collider_mask(self.scene, L, self.scene_dir))
        face_shape = (dim,) + tuple(c + 3 for c in L.n)
        cell_shape = tuple(c + 2 for c in L.n)
        off = (-1,) * dim
        self.vel = ti.field(f, shape=face_shape, offset=(0,) + off)  # component d on its faces
        self.scalars = ti.field(
            f, shape=(2,) + cell_shape, offset=(0,) + off
        )  # smoke density, temperature [K]
        self.pressure = ti.field(f, shape=cell_shape, offset=off)  # kinematic: p / rho [m^2/s^2]
        self.flags = ti.field(ti.u8, shape=cell_shape, offset=off)
        self.kinds = ti.field(ti.u8, shape=face_shape, offset=(0,) + off)
        self.wall_vel = ti.Vector.field(dim, f, shape=(dim, 2))
        self.flags.from_numpy(L.flags)
        self.kinds.from_numpy(np.stack(L.kinds))
        self.wall_vel.from_numpy(L.wall_velocity.astype(self.npf))
        self.stats = ti.field(ti.f64, shape=2)  # max speed, non-finite count

        self.solid_vel = ti.field(f, shape=face_shape, offset=(0,) + off) if self.moving else None
        if self.moving:
            self.solid_vel.from_numpy(self.cols.face_velocity(self._own, 0.0).astype(self.npf))
        self.bc = Boundary(L, self.kinds, self.wall_vel, self.solid_vel)
        self.sources = Sources(
            L,
            f,
            self.bc,
            self.vel,
            self.scalars,
            self.flags,
            self.entity.jets,
            self.mat,
            self.scene.sim.gravity_vec,
        )
        self.advector = Advector(L, f, self.bc, self.vel, self.scalars, 2, self.opts.advection)
        self.diffusion = (
            Diffusion(L, f, self.bc, self.vel, self.mat.viscosity, self.opts.viscosity_tolerance)
            if self.mat.viscosity > 0
            else None
        )
        self.projection = Projection(L, f, self.bc, self.vel, self.pressure, self.opts, self.moving)
        self._make_kernels()
        moving = self._upload_initial()
        if moving:  # make the initial velocity discretely divergence-free (frame 0 included)
            self.projection.solve(1.0)
            self.pressure.fill(0.0)
        self._built = True
        self._version = 0
        self._cache: dict = {}
        self.frame_check()

    def _upload_initial(self) -> bool:
        L, e, m = self.layout, self.entity, self.mat
        dim = self.dim
        from simcli.geometry.regions import points_in_shape

        inside = np.ones(L.n, dtype=bool)
        if e.morph is not None:
            cells = L.cell_centres()
            inside = points_in_shape(e.morph, np.stack([c.ravel() for c in cells], axis=1)).reshape(L.n)
            del cells
        dens = np.where(inside, m.initial_density if e.morph is not None else 0.0, 0.0)
        t_in = m.initial_temperature if m.initial_temperature is not None else m.ambient_temperature
        temp = np.where(inside, t_in, m.ambient_temperature)
        solid = L.flags[(slice(1, -1),) * dim] == SOLID
        dens[solid] = 0.0
        temp[solid] = m.ambient_temperature
        self.scalars.from_numpy(np.stack([self._pad_cell(dens), self._pad_cell(temp)]))
        moving = False
        vel = np.zeros((dim,) + tuple(c + 3 for c in L.n), dtype=self.npf)
        for d in range(dim):
            shape = tuple(L.n[a] + (1 if a == d else 0) for a in range(dim))
            if (e.velocity is None or e.velocity[d] == 0) and e.velocity_field is None:
                continue  # nothing to set: skip the float64 face coordinates (400 MB at 256^3)
            xf = L.face_centres(d)
            u = np.zeros(shape)
            if e.velocity is not None and e.velocity[d] != 0:
                mask = np.ones(u.shape, dtype=bool)
                if e.morph is not None:
                    mask = points_in_shape(e.morph, np.stack([c.ravel() for c in xf], axis=1)).reshape(
                        u.shape
                    )
                u = np.where(mask, float(e.velocity[d]), 0.0)
            if e.velocity_field is not None:
                u = u + eval_field(e.velocity_field[d], xf)
            moving |= bool(np.any(u != 0))
            vel[(d,) + tuple(slice(1, 1 + k) for k in u.shape)] = u
        self.vel.from_numpy(vel)
        self._init_boundary()
        return moving

    def _pad_cell(self, a: np.ndarray) -> np.ndarray:
        out = np.zeros(tuple(c + 2 for c in self.layout.n), dtype=self.npf)
        out[(slice(1, -1),) * self.dim] = a
        return out

    def _make_kernels(self) -> None:
        L, f, bc = self.layout, self.f, self.bc
        dim = self.dim
        vel, S, stats, at = self.vel, self.scalars, self.stats, bc.at
        cell_rng = bc.cell_range()
        face_rng = [bc.face_range(d) for d in range(dim)]
        f64 = f == ti.f64

        fixed = bc.set_fixed(vel)

        @ti.kernel
        def init_boundary():
            bc.each_face(fixed)
            bc.fill_face_ghosts(vel)
            bc.fill_cell_ghosts(S, 2)

        @ti.func
        def finite(a):
            # exponent bits all ones = inf or NaN; a bit test because fast-math may drop isnan
            ok = True
            if ti.static(f64):
                ok = ((ti.bit_cast(a, ti.i64) >> 52) & 0x7FF) != 0x7FF
            else:
                ok = ((ti.bit_cast(a, ti.i32) >> 23) & 0xFF) != 0xFF
            return ok

        @ti.kernel
        def frame_stats():
            stats[0] = 0.0
            stats[1] = 0.0
            for I in ti.grouped(ti.ndrange(*cell_rng)):
                v2 = ti.cast(0.0, ti.f64)
                for a in ti.static(range(dim)):
                    J = I
                    J[a] += 1
                    v = 0.5 * (vel[at(a, I)] + vel[at(a, J)])
                    v2 += ti.cast(v, ti.f64) ** 2
                bad = 0
                if not (finite(S[at(0, I)]) and finite(S[at(1, I)])):
                    bad = 1
                for a in ti.static(range(dim)):
                    if not finite(vel[at(a, I)]):
                        bad = 1
                if bad:
                    stats[1] += 1.0
                else:
                    ti.atomic_max(stats[0], ti.sqrt(v2))
            for d in ti.static(range(dim)):  # the faces on the upper walls
                for I in ti.grouped(ti.ndrange(*face_rng[d])):
                    if I[d] == L.n[d] and not finite(vel[at(d, I)]):
                        stats[1] += 1.0

        self._init_boundary, self._frame_stats = init_boundary, frame_stats

    # ---------------------------------------------------------------- stepping

    def _move_colliders(self, t: float) -> None:
        """Moving colliders (moving.py): the solid cells at time t, the face kinds, the operators and the
        solid faces' velocities, uploaded."""
        L = self.layout
        self._own = self.cols.owner(t)
        compute_flags(L, self._own >= 0)
        self.flags.from_numpy(L.flags)
        self.kinds.from_numpy(np.stack(L.kinds))
        self.solid_vel.from_numpy(self.cols.face_velocity(self._own, t).astype(self.npf))
        self.projection.update_operator()
        if self.diffusion is not None:
            self.diffusion.update_operator()

    def collider_loads(self) -> dict[str, np.ndarray]:
        """Named collider -> (dim + 3) impulse [N s] and moment [N m s] of the fluid's pressure on it since
        the last call, summed over the substeps (moving.py); resets them."""
        if not self._built or not self.named:
            return {}
        out, self.cols.acc = self.cols.acc, {}
        return {
            c.name: out.get(c.name, np.zeros(self.dim + 3)) for c in self.cols.specs if c.name is not None
        }

    def substep(self, dt: float) -> None:
        if self.moving:  # the solids at the substep's end pose, their surface velocity the faces' values
            self._move_colliders(self.time + dt)
        if self.opts.reflection:
            its, vits = self._reflection_step(dt)
            res, rel = self.projection.last_residual(dt / 2)
        else:
            self.advector.advect(dt)  # advect
            self.sources(dt, self.time)  # add_sources
            vits = 0
            if self.diffusion is not None:  # diffuse
                vits, _ = self.diffusion.solve(dt)
            its, res, rel = self.projection.solve(dt)  # project
        h = self.hist
        if len(h["iterations"]) < HISTORY_KEEP:
            h["iterations"].append(its)
            h["residual"].append(res)
            h["relative_residual"].append(rel)
            h["viscosity_iterations"].append(vits)
            h["converged"].append(self.projection.converged(dt / 2 if self.opts.reflection else dt))
        if self.named:  # the pressure's impulse on named colliders (one readback of the pressure)
            for k, v in self.cols.loads(self._own, self._cell(self.pressure), self.time + dt).items():
                self.cols.acc[k] = self.cols.acc.get(k, 0.0) + v * dt
        self.time += dt
        self.substeps += 1
        self._version += 1

    def _reflection_step(self, dt: float) -> tuple[int, int]:
        """Advection-reflection (Zehnder, Narain & Thomaszewski 2018): advect and project over dt/2,
        reflect the projected field about the divergence-free space (u -> 2 P u - u, i.e. subtract the
        pressure gradient once more), advect that over dt/2 by the projected field, project again.
        The splitting then loses far less kinetic energy than Stam's one projection per step."""
        half = 0.5 * dt
        vits = 0
        self.advector.advect(half)
        self.sources(dt, self.time)  # the whole substep's forces and sources, projected with the first half
        if self.diffusion is not None:
            vits += self.diffusion.solve(half)[0]
        its = self.projection.solve(half)[0]
        self.advector.nodes()  # the advecting velocity of the second half: the projected field
        self.projection.reflect()
        self.advector.advect(half, nodes_ready=True)
        if self.diffusion is not None:
            vits += self.diffusion.solve(half)[0]
        its += self.projection.solve(half)[0]
        return its, vits

    # ------------------------------------------------------------ frame checks

    def frame_check(self) -> dict[str, FrameStats]:
        self._frame_stats()
        st = self.stats.to_numpy()  # [max speed, non-finite cells]
        return frame_stats_per_body([self.name], st[0:1], st[1:2])

    def max_speed(self) -> float:
        self._frame_stats()
        return float(self.stats[0])

    def stable_dt(self, horizon: float = 0.0) -> float:
        """cfl x dx / max speed: the substep `substeps: auto` aims at. Semi-Lagrangian advection and
        the implicit viscosity are stable at any step; this only bounds the accuracy loss."""
        v = self.max_speed() if self._built else 0.0
        if self._built and self.moving and math.isfinite(v):  # a moving solid must not jump cells either
            v = max(v, self.cols.max_surface_speed(self.time))
        return self.opts.cfl * min(self.layout.dx) / v if v > 0 and math.isfinite(v) else math.inf

    def length_scale(self) -> float:
        return min(self.layout.dx)

    def runaway_advice(self, name: str, sim) -> str:
        subs = sim.substeps if sim.substeps != "auto" else "auto"
        return (
            f"lower sim.dt (now {sim.dt:g} s), raise sim.substeps (now {subs}) or use substeps: auto; "
            f"the limit is solvers.sf.max_cfl (now {self.opts.max_cfl:g} cells per substep)"
        )

    def runaway_cfl(self) -> float:
        # Semi-Lagrangian advection is stable at any CFL number: the guard fires at solvers.sf.max_cfl,
        # not at the particle methods' RUNAWAY_CFL
        return self.opts.max_cfl

    # ------------------------------------------------------------------ output

    def _faces(self, d: int) -> np.ndarray:
        """Component d on its faces (n + e_d), float64, x y z index order."""
        a = self._vel_np()[d]
        n = self.layout.n
        return a[tuple(slice(1, 1 + n[b] + (1 if b == d else 0)) for b in range(self.dim))]

    def _vel_np(self) -> np.ndarray:
        hit = self._cache.get("_vel")
        if hit is None or hit[0] != self._version:
            hit = (self._version, self.vel.to_numpy().astype(np.float64))
            self._cache["_vel"] = hit
        return hit[1]

    def _cell(self, fld) -> np.ndarray:
        return fld.to_numpy().astype(np.float64)[(slice(1, -1),) * self.dim]

    def _cell_faces(self, d: int) -> tuple[tuple, tuple]:
        """Index tuples picking, from an array of the faces normal to axis d, each cell's low and high
        face."""
        lo = [slice(None)] * self.dim
        hi = [slice(None)] * self.dim
        lo[d] = slice(0, -1)
        hi[d] = slice(1, None)
        return tuple(lo), tuple(hi)

    def cell_velocity(self) -> np.ndarray:
        """Velocity at the cell centres (mean of the two faces), shape n + (dim,), x y z index order."""
        comps = []
        for d in range(self.dim):
            F = self._faces(d)
            lo, hi = self._cell_faces(d)
            comps.append(0.5 * (F[lo] + F[hi]))
        return np.stack(comps, axis=-1)

    def divergence(self) -> np.ndarray:
        """Cell divergence [1/s] of the face velocities (float64, on the host; 0 in solid cells)."""
        div = np.zeros(self.layout.n)
        for d in range(self.dim):
            F = self._faces(d)
            lo, hi = self._cell_faces(d)
            div += (F[hi] - F[lo]) / self.layout.dx[d]
        div[self.layout.flags[(slice(1, -1),) * self.dim] == SOLID] = 0.0
        return div

    def vorticity(self) -> np.ndarray:
        u = self.cell_velocity()
        dx = self.layout.dx

        def grad(c, a):
            return np.gradient(u[..., c], dx[a], axis=a) if u.shape[a] > 1 else np.zeros(u.shape[:-1])

        if self.dim == 2:
            return grad(1, 0) - grad(0, 1)
        return np.stack([grad(2, 1) - grad(1, 2), grad(0, 2) - grad(2, 0), grad(1, 0) - grad(0, 1)], axis=-1)

    def _full(self, key: str) -> np.ndarray:
        hit = self._cache.get(key)
        if hit is not None and hit[0] == self._version:
            return hit[1]
        if key == "velocity":
            arr = self.cell_velocity()
        elif key == "pressure":
            arr = self.mat.rho * self._cell(self.pressure)
        elif key in ("density", "temperature"):
            arr = self.scalars.to_numpy().astype(np.float64)[
                (0 if key == "density" else 1,) + (slice(1, -1),) * self.dim
            ]
        elif key == "divergence":
            arr = self.divergence()
        elif key == "vorticity":
            arr = self.vorticity()
        elif key == "solid":
            arr = (self.layout.flags[(slice(1, -1),) * self.dim] == SOLID).astype(np.float64)
        else:
            raise KeyError(f"unknown SF output field {key!r}; known: {', '.join(OUTPUT_FIELDS)}")
        self._cache[key] = (self._version, arr)
        return arr

    def entity_arrays(self, name: str, fields: list[str]) -> dict[str, np.ndarray]:
        """Grid fields in VTK order (nz, ny, nx[, c]): the x y z index order transposed."""
        out = {}
        for fld in fields:
            a = self._full(fld)
            axes = tuple(reversed(range(self.dim)))
            if a.ndim > self.dim:
                axes = axes + (self.dim,)
            out[fld] = np.ascontiguousarray(a.transpose(axes), dtype=np.float32)
        return out

    def output_fields(self) -> dict[str, tuple[int, str]]:
        d = self.dim
        return {
            "velocity": (d, "m/s"),
            "pressure": (1, "Pa"),
            "density": (1, "1"),
            "temperature": (1, "K"),
            "divergence": (1, "1/s"),
            "vorticity": (3 if d == 3 else 1, "1/s"),
            "solid": (1, "1"),
        }

    def default_fields(self, name: str) -> list[str]:
        return list(DEFAULT_FIELDS)

    def entity_kind(self, name: str) -> str:
        return "grid"

    def steady(self) -> dict | None:
        """solvers.sf.steady_tolerance: the largest face-velocity change since the last written frame per
        second [m/s^2], on the host (once per frame); the run stops once it is at or below the tolerance."""
        tol = self.opts.steady_tolerance
        if tol <= 0:
            return None
        v = self.vel.to_numpy().astype(np.float64)
        prev, self._steady_prev = getattr(self, "_steady_prev", None), (self.time, v)
        if prev is None or self.time <= prev[0]:
            return None
        rate = float(np.abs(v - prev[1]).max()) / (self.time - prev[0])
        self._steady_rate = rate
        return (
            {"criterion": "solvers.sf.steady_tolerance", "change_rate": rate, "tolerance": tol}
            if rate <= tol
            else None
        )

    def entity_grid(self, name: str):
        L = self.layout
        return tuple(L.n), tuple(float(o) for o in L.origin), tuple(float(h) for h in L.dx)

    def entity_size(self, name: str) -> int:
        return self.layout.cells

    def owns(self, name: str) -> bool:
        return name == self.name

    # ------------------------------------------------------------------- state

    def get_state(self) -> dict[str, np.ndarray]:
        return {
            "velocity": self.vel.to_numpy(),
            "scalars": self.scalars.to_numpy(),
            "pressure": self.pressure.to_numpy(),
            "time": np.array([self.time]),
        }

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        for key, fld in (("velocity", self.vel), ("scalars", self.scalars), ("pressure", self.pressure)):
            upload_state_array(fld, state, key, fld.shape, self.npf, "SF")
        if "time" in state:
            self.time = float(np.asarray(state["time"]).reshape(-1)[0])
        if self.moving:  # the solids at the resumed pose
            self._move_colliders(self.time)
        self._version += 1

    # ------------------------------------------------------------------ counts

    def counts(self) -> dict[str, int]:
        fluid = int(np.count_nonzero(self.layout.levels[0].diag > 0)) if self.layout.levels else 0
        return {"cells": self.layout.cells, "fluid_cells": fluid}

    def info(self) -> dict[str, Any]:
        L, h = self.layout, self.hist
        its = h["iterations"]
        d = {
            "grid": f"MAC {'x'.join(map(str, L.n))}, dx {', '.join(f'{x:.6g}' for x in L.dx)} m",
            "advection": self.opts.advection,
            "pressure_solver": self.opts.pressure_solver,
            "tolerance": self.opts.tolerance,
            "relative_tolerance": self.opts.relative_tolerance,
            "reflection": self.opts.reflection,
            "multigrid_levels": [list(lv.n) for lv in self.projection.levels] if self._built else [],
            "viscosity": self.mat.viscosity,
            "substeps": self.substeps,
        }
        if its:
            d.update(
                iterations_mean=float(np.mean(its)),
                iterations_max=int(np.max(its)),
                residual_max=float(np.max(h["residual"])),
                relative_residual_max=float(np.max(h["relative_residual"])),
                steps_above_tolerance=(
                    len(h["converged"]) - int(np.sum(h["converged"])) if self.projection._checking else None
                ),
            )
            if self.diffusion is not None:
                d["viscosity_iterations_mean"] = float(np.mean(h["viscosity_iterations"]))
        if self.opts.steady_tolerance > 0:
            d["steady_tolerance"] = self.opts.steady_tolerance
            d["steady_change_rate_last"] = getattr(self, "_steady_rate", None)
        d["per_substep"] = {
            "iterations": list(map(int, its)),
            "residual": [float(f"{r:.4g}") for r in h["residual"]],
            "relative_residual": [float(f"{r:.4g}") for r in h["relative_residual"]],
        }
        if self.diffusion is not None:
            d["per_substep"]["viscosity_iterations"] = list(map(int, h["viscosity_iterations"]))
        return d
